"""Floor 3 of the house: the calibration pipelines, straight runs over typed stage results.

    full.run_calibration    capture -> SfM -> BA -> world frame -> bundle (``dome-calib calibrate``)
    quick.run_quick         the changed cameras only (``--only-changed``)
    stages                  the SfM and BA stages as the pipeline calls them (their results: types)
    finish                  cameras to check, then the bundle and its report replacing OUT whole
    types                   options, inputs and results of a calibration
    capture                 what capture.json says (scenes, cameras, capture nodes)
    workstate               the resumable work folder
    cluster                 where the SfM's tasks run (local pool or Dask) and what ran where
    session                 every pillar of a capture session into one bundle (``dome-calib session``)
    demo                    a synthetic session through the session pipeline, judged against its truth
"""
