"""File formats (edges layer): calibration.json, measurements.csv, MATLAB export."""
