"""File formats: every file microcal reads or writes (cameras.json, calibration.json,
results.json, measurements.csv, the run directory and its records, rig files, images, .mat
export). Reading and writing only: no procedure, workflow, report or command-line code."""
