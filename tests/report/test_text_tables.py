"""What the calibration commands print of the consistency figures (report.text_tables)."""

from __future__ import annotations

from microcal.report.text_tables import consistency_lines

FIGURES = {
    "held_out": {
        "cameras": {"left": {"training_rms_px": 0.08, "held_out_rms_px": 0.088, "ratio": 1.1},
                    "right": {"training_rms_px": None, "held_out_rms_px": None, "ratio": None}},
        "joint": {"training_rms_px": 0.1, "held_out_rms_px": 0.105, "ratio": 1.05},
    },
    "pitch": {"x": {"nominal_um": 1000.0, "mean_um": 999.84, "error": -0.00016,
                    "rms_error": 0.0013, "worst_cell_error": -0.0008, "segments": 2808},
              "y": {"nominal_um": 1000.0, "mean_um": 1000.1, "error": 0.0001,
                    "rms_error": 0.0014, "worst_cell_error": None, "segments": 5}},
    "closure": [{"cameras": ["left", "middle", "right"], "baseline_um": 9692.8,
                 "translation_gap": 0.00063, "rotation_gap_deg": 0.008}],
}  # fmt: skip


def test_consistency_lines_say_each_figure_in_words():
    lines = consistency_lines(FIGURES)
    assert lines[0] == (
        "held-out views (each fold of the views predicted by the others) against the views "
        "fitted: left 0.088 px against 0.080 px (x1.10); all cameras together 0.105 px "
        "against 0.100 px (x1.05)"
    )
    assert lines[1] == (
        "target pitch triangulated along x: 999.84 µm against 1000 µm (-0.016 %; worst ninth "
        "of the field -0.080 %)"
    )
    assert lines[2] == "target pitch triangulated along y: 1000.10 µm against 1000 µm (+0.010 %)"
    assert lines[3] == (
        "left to right calibrated directly against composed through middle: translations "
        "differ by 0.063 % of 9693 µm, rotations by 0.008 deg"
    )
    assert consistency_lines({}) == []
