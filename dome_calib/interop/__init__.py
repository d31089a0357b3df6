"""Export a calibration bundle to other tools' formats and import theirs: one module per format (COLMAP,
aniposelib, Pose2Sim, EasyMocap, nerfstudio, Blender out; Qualisys, Caliscope, Kalibr in), one row per format in
:mod:`dome_calib.interop.registry`, and :mod:`dome_calib.interop.convert` for what every format shares. See
docs/interop.md.
"""
