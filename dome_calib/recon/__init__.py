"""Reconstruction stages that consume a calibration bundle: project, triangulate across synchronised streams,
Kinect depth to world. See docs/recon.md for the file formats of the CLI."""
