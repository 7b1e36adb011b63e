"""Experiments on the simulated platform: the demo, the population study, the station demo
and the camera-model trial. They need the simulator's ground truth, so they run on it alone;
the procedures they build on (``microcal.procedures``) run on any rig."""
