"""Control (above devices and vision): drive a manipulator to positions in {G}.

Feed-forward through a compensator of the identified model (:mod:`.feedforward`) and the
conditions an evaluation compares (:mod:`.conditions`).
"""
