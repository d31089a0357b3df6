"""Groups of people from unlabelled per-camera detections: ``dome-calib reconstruct``.

The modules, in the order the data flows (each a stage with typed inputs and results, testable alone):

- :mod:`.sources`: every camera's people grouped by stream (layouts checked against the sync tables; in memory or
  read from OpenPose files chunk by chunk);
- :mod:`.resample`: a batch of universal times: each stream's people there (2D matching of the bracketing frames);
- :mod:`.proposals`: who might be there: 3D proposals from bounded view pairs;
- :mod:`.assign`: which detection in which view is whom (assignment, residual proposals, second pass);
- :mod:`.bodies`: robust triangulation of the assigned detections, then the bodies of each time;
- :mod:`.joint_check`: which triangulated joints a body keeps (called between the two steps of ``bodies``);
- :mod:`.agreement`: how well each camera agrees with the bodies;
- :mod:`.tracking`: ids over time, once over the whole session; :mod:`.bridging`: the times inside a track's gaps
  searched again with its prediction (a person whose evidence is thin there kept under his id);
- :mod:`.temporal`: one body per person over time (constant bones, smooth motion, every detection weighed against
  the body) over a span of times; :mod:`.windows`: the session's bone lengths and camera noise measured once, and
  the fit in windows fixed by the session's time index;
- :mod:`.run`: the straight run of the above (the bodies of each time, then tracks and the body over time);
  :mod:`.chunks`: long sessions on an executor (chunks of times, then windows);
- :mod:`.scene_io`: body3DScene files and cameras.json; :mod:`.commands`: the file-level stage behind the command.

:mod:`.matching` holds what several stages share (greedy matching, skeleton distance, de-duplication).
"""
