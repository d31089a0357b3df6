"""Clock alignment from LTC and sync tables.

Modules: :mod:`~timecode.sync.clock` (decoded frame starts -> piecewise clock models), :mod:`~timecode.sync.session`
(on-disk session layout and loader), :mod:`~timecode.sync.tables` (universal time of every frame, sync tables,
report), :mod:`~timecode.sync.match` (HD frame -> Kinect colour/depth frames), :mod:`~dome_calib.synth.sync_session`
(synthetic sessions with known truth), :mod:`~timecode.sync.pipeline` (decode + fit + write, used by the CLI).
"""
