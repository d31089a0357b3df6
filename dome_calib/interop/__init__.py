"""Export a calibration bundle to other tools' formats and import theirs (COLMAP, aniposelib, Pose2Sim,
EasyMocap, nerfstudio): one module per format, :mod:`dome_calib.interop.convert` runs them. See docs/interop.md.
"""
