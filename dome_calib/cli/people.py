"""`dome-calib reconstruct`: a thin shell over dome_calib.recon.people.commands.

The stage is imported inside the command: `dome-calib --help` starts without loading it. SIGINT / SIGTERM: one
line, exit 130 (pycolmap's C handler, loaded with the stage, is put back to ours).
"""
from __future__ import annotations

from pathlib import Path

import typer

from dome_calib.errors import interrupt_as_one_line


def reconstruct(
    detections: Path = typer.Argument(..., help="Folder of OpenPose output: one sub-folder per camera (named as in "
                                      "the bundle, or mapped with --camera-map), one JSON file per frame "
                                      "(<name>_<frame:012d>_keypoints.json or cam01.0042.json; the last number is "
                                      "the camera's own frame index).", show_default=False),
    bundle: Path = typer.Option(..., "--bundle", help="Calibration bundle folder (calibration_<seq>.json; its "
                                "synctables/ksynctables give each camera's frame times; without them all cameras "
                                "share one frame index: cameras of one stream only).", show_default=False),
    out: Path = typer.Option(None, "-o", "--out", help="Folder for body3DScene_<frame>.json (one per time, every "
                             "person with an id), cameras.json and index.html (a page to watch the people; default: "
                             "<DETECTIONS>_people beside DETECTIONS; never inside DETECTIONS or the bundle)."),
    body_model: str = typer.Option(None, "--body-model", help="The detector's model: BODY_25, BODY_25B, COCO_18 or "
                                   "PANOPTIC19. Needed for 25-joint files (BODY_25 and BODY_25B have the same "
                                   "length); checked against the files' joint order."),
    camera_map: str = typer.Option(None, "--camera-map", help="Folder-to-camera names, e.g. "
                                   "'cam01=00_01,cam02=00_02', or a JSON file {\"cam01\": \"00_01\"}."),
    reference: str = typer.Option(None, "--reference", help="Stream whose frames are the output times (vga, hd, "
                                  "KINECTNODE<n>; default vga, else hd)."),
    min_views: int = typer.Option(3, "--min-views", help="A person must be seen by this many cameras (2 or more)."),
    smooth: int = typer.Option(0, "--smooth", help="Smooth each person's per-frame joints over this many frames "
                               "either side (a local straight-line fit: no lag for steady motion); 0 = off."),
    per_frame: bool = typer.Option(False, "--per-frame", help="Each time's own triangulation only, without the body "
                                   "over time (constant bones, smooth motion, every detection weighed against the "
                                   "body; the default and the better result)."),
    fps: str = typer.Option(None, "--fps", help="Frame rate of the detections when the bundle has no sync tables "
                            "(for univTime; e.g. 60, 30000/1001, 1 for a time-lapse rig). Without sync tables the rate "
                            "comes from --fps or --videos; neither is refused (no rate is assumed)."),
    videos: Path = typer.Option(None, "--videos", help="Folder of the cameras' videos (.mp4, .avi, .mov, .mkv; one "
                                "level of sub-folders): their frame rate is the detections' when the bundle has no "
                                "sync tables (they must agree, and with --fps if given)."),
    depth: Path = typer.Option(None, "--depth", help="Folder of Kinect depth frames (KINECTNODE<n>/depth_<k>.png, "
                               "16-bit millimetres, k the depth sync table's index): a joint that a Kinect sees "
                               "through (in front of the surface it measured, beyond its noise) is dropped. Needs "
                               "the bundle's Kinect calibration and depth sync tables."),
    images: Path = typer.Option(None, "--images", help="Folder of the cameras' images: per camera a video or a "
                                "folder of frames (images.json maps camera names to them, else <camera>.mp4 or "
                                "<camera>/). After the people, the dense patch trajectory stream is tracked on them, "
                                "each patch given the body part it moves with, into OUT/patches.parquet."),
    patch_seeds: str = typer.Option("auto", "--patch-seeds", help="How --images seeds its patches: auto (the "
                                    "default: sweep where the reference stream's cameras stand within 45 deg of "
                                    "their nearest neighbour, median, else skeleton; the output says which and "
                                    "why), sweep (corners put in 3D by a depth sweep in nearby cameras: a dense "
                                    "dome), features (SIFT matched along epipolar lines), skeleton (corners on the "
                                    "people put in 3D by their bodies' capsules, refined photometrically nearby: "
                                    "a few cameras far apart; the people are the depth prior)."),
    correct_offsets: bool = typer.Option(False, "--correct-offsets", help="A camera flagged for its offset (its "
                                         "joints to one side of where the others put them: turned since "
                                         "calibration) gets its principal point moved by the offset measured, and "
                                         "the people are made again (up to 4 times); cameras.json says the shifts. "
                                         "Not with --images."),
    workers: int = typer.Option(1, "--workers", help="Processes for long sessions (chunks of 600 times, then the "
                                "body over time's windows, the --images patch clouds; 1 to 1024)."),
    scheduler: str = typer.Option(None, "--scheduler", help="Dask scheduler (tcp://HOST:PORT) to run the chunks, "
                                  "windows and patch clouds on instead of local processes."),
) -> None:
    """Reconstruct groups of people from per-camera OpenPose detections: find each person across the cameras,
    triangulate their joints in the world frame (cm), keep their id over time, and write one Panoptic
    body3DScene file per time plus cameras.json (how well each camera agrees: a camera that moved shows up)."""
    with interrupt_as_one_line("dome-calib", "the output folder is as it was; rerun the same command"):
        from dome_calib.cli.progress import ProgressBars
        from dome_calib.pipeline.cluster import open_executor
        from dome_calib.pipeline.people_page import people_page_writer
        from dome_calib.recon.people.commands import (OFFSET_ROUNDS, check_correct_offsets, check_workers,
                                                      format_summary, people_options, plan_reconstruction,
                                                      run_reconstruction)

        options = people_options(min_views=min_views, smooth=smooth, fps=fps, per_frame=per_frame)
        check_workers(workers)
        check_correct_offsets(correct_offsets, images)
        plan = plan_reconstruction(detections, bundle, out, body_model=body_model, camera_map=camera_map,
                                   reference=reference, options=options,
                                   depth_folder=depth, videos=videos, images=images)  # every input, in seconds
        patches = None
        if images is not None:
            from dome_calib.recon.patches.stage import plan_patches
            patches = plan_patches(plan, seed_method=patch_seeds)  # the images' contents, before any work
        page = people_page_writer(plan.out, bundle, detections, camera_map=camera_map, body_model=plan.model.value,
                                  files=plan.source.files)
        with open_executor(None, scheduler, workers=workers) as executor, ProgressBars(transient=True) as bars:
            summary = run_reconstruction(plan, executor=executor, progress=bars.task("reconstructing times"),
                                         page=page, after_people=None if patches is None else (
                                             lambda seq: patches.run(seq.times_ms, seq.bodies,
                                                                     bars.task("tracking patch clouds"),
                                                                     executor=executor)),
                                         offset_rounds=OFFSET_ROUNDS if correct_offsets else 0)
        typer.echo(format_summary(summary))
        if patches is not None:
            typer.echo(patches.summary)


def register(app: typer.Typer) -> None:
    """Add `reconstruct` to the `dome-calib` app."""
    app.command()(reconstruct)
