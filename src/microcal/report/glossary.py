"""The words of the report and the command line that a newcomer meets first, explained.

The report shows them in its last section (``#terms``); ``docs/glossary.md`` holds the same
terms (a test keeps the two in step).
"""

from __future__ import annotations

__all__ = ["GLOSSARY"]

#: Term -> its meaning, one or two sentences each, in the order a report reads.
GLOSSARY: dict[str, str] = {
    "{G}": "The frame the cameras define (after the stereo calibration); every position in "
    "µm that microcal prints, and every target it is given, is in {G}.",
    "joints, dx dy dz": "The manipulator's axis commands in µm, as its controller takes them; "
    "the kinematic model maps them to the tip's position in {G}.",
    "uncalibrated": "The condition in which the joints are commanded as given, through no "
    "model: what the manipulator does without microcal.",
    "matrix": "The condition that commands the joints through the matrix model (a linear "
    "map of the joints, Eq 4.5), inverted exactly.",
    "optimal": "The condition that commands the joints through the polynomial model (Eq 4.6: "
    "terms up to the second power), inverted by the optimal compensator (Eq 4.17 to 4.19).",
    "closed loop": "After the optimal condition's move, the cameras measure the tip and the "
    "joints are corrected until it is within the tolerance with 90 % probability, a "
    "correction is below the positioner's resolution, or the cap of corrections is reached.",
    "vision / truth": "A figure measured by the calibrated cameras (vision), or by the "
    "simulator's ground truth (truth, on the simulated platform only).",
    "direction terms, sx sy sz": "Inputs of the model that say from which side each joint "
    "arrived (+1 moving up, -1 moving down): their coefficients are the reversal error "
    "(hysteresis). A model with them is driven with every joint arriving moving up.",
    "T": "The temperature input of a model (°C), with its terms T and T² (Eq 4.10).",
    "AP, AP_P": "ISO 9283 pose accuracy: the distance from the commanded pose to the mean of "
    "the poses reached, per axis (AP x, y, z) and as a length (AP_P), µm.",
    "RP": "ISO 9283 pose repeatability: the radius of the sphere that holds the poses "
    "reached at one commanded pose (mean plus three standard deviations), µm.",
    "vAP": "ISO 9283 multi-directional pose accuracy variation: how far apart the mean poses "
    "reached from different directions lie, µm.",
    "AD, RD": "ISO 9283 distance accuracy and repeatability: the error of the distance moved "
    "between two poses, and its spread, µm.",
    "Ω": "The decoupling test's integration index (Eq 5.2): the undesired "
    "displacement of the still axes summed over the samples; compare within one run.",
    "oracle": "On the simulated platform only: the compensator that knows the simulator's "
    "true kinematics; no method can beat it from the same measurements, so it is the "
    "reference the others are measured against.",
    "validation error": "The model's error (Eq 5.1) at poses it was not fitted to: "
    "the last poses of a run, or each fold of a cross-validation.",
    "reprojection RMS": "How far, in pixels, the calibrated cameras put the calibration "
    "target's features from where they were detected; well under 0.1 px is good.",
}
