"""Blender cameras: a Python script that Blender runs (``blender --python dome_cameras.py``, or Text Editor >
Run Script; ``blender --background --python dome_cameras.py -- dome.blend`` saves the scene).

The script makes one camera object per camera in a collection "dome_calib cameras", at its pose in a z-up world
in metres (Blender's: our -y up turned to +z, x kept), and one scene per camera, named after it, whose render
settings are that camera's: Blender keeps the image size and the pixel aspect per scene, not per camera, so this is
the only way every camera renders exactly as it sees (the scene open when the script runs becomes the first
camera's). Blender's camera (checked with ``bpy`` 5.0: ``world_to_camera_view``):

- ``sensor_fit = 'HORIZONTAL'``, ``sensor_width`` 36 mm, ``lens = fx * 36 / width`` (mm): fx in pixels;
- ``pixel_aspect_x / pixel_aspect_y = fy / fx`` (the larger one 1: Blender takes values from 1 to 200);
- ``shift_x = (width / 2 - cx') / width``, ``shift_y = (cy' - height / 2) / (width * fy / fx)``, where
  ``cx' = cx + 0.5``, ``cy' = cy + 0.5`` (Blender's pixels start at the image's corner, ours at the first pixel's
  centre);
- ``matrix_world = [R^T diag(1, -1, -1) | centre]``: Blender's camera looks along its -z with y up.

What Blender cannot hold: lens distortion (its camera is a pinhole); the export says, per camera, how far that
moves the point seen at the image corner. Blender stores these numbers in 32-bit floats: ~1e-4 px.
The camera data rides in the script as one JSON string literal (data, never code).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dome_calib.interop.common import ForeignCamera, Written, corner_shift_px, dropped_terms_line
from dome_calib.exact import centre, matmul3, transpose3

SENSOR_WIDTH_MM = 36.0
OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0])


def blender_camera(cam: ForeignCamera) -> dict:
    """The Blender settings of one camera (see the module docstring)."""
    w, h = cam.size
    fx, fy = float(cam.K[0, 0]), float(cam.K[1, 1])
    cx, cy = float(cam.K[0, 2]) + 0.5, float(cam.K[1, 2]) + 0.5
    ratio = fy / fx
    world_from_cam = np.eye(4)
    world_from_cam[:3, :3] = matmul3(transpose3(cam.R), OPENGL_FROM_OPENCV)
    world_from_cam[:3, 3] = centre(cam.R, cam.t)
    return {
        "name": cam.name, "resolution": [int(w), int(h)],
        "pixel_aspect": [ratio, 1.0] if ratio >= 1.0 else [1.0, 1.0 / ratio],
        "lens_mm": fx * SENSOR_WIDTH_MM / w, "sensor_width_mm": SENSOR_WIDTH_MM,
        "shift": [(w / 2 - cx) / w, (cy - h / 2) / (w * ratio)],
        "matrix_world": world_from_cam.tolist(),
        "K": np.asarray(cam.K, dtype=float).tolist(), "dist": np.asarray(cam.dist, dtype=float).tolist(),
    }


_SCRIPT = '''"""Dome cameras for Blender, written by dome-calib export --to blender ({count} cameras, metres, z up).

Run: blender --python <this file>    (or Text Editor > Run Script; add "-- FILE.blend" to save the scene)
One camera object per camera (collection "dome_calib cameras"); one scene per camera, named after it, with that
camera's image size and pixel aspect (Blender keeps them per scene). Lens distortion is not held by Blender's
camera: each object keeps our K and dist as custom properties "dome_calib_K" and "dome_calib_dist".
"""
import json
import sys

import bpy
import mathutils

CAMERAS = json.loads({data})


def build():
    first_scene = bpy.context.scene
    collection = bpy.data.collections.new("dome_calib cameras")
    first_scene.collection.children.link(collection)
    for i, cam in enumerate(CAMERAS):
        data = bpy.data.cameras.new(cam["name"])
        data.sensor_fit = "HORIZONTAL"
        data.sensor_width = cam["sensor_width_mm"]
        data.lens = cam["lens_mm"]
        data.shift_x, data.shift_y = cam["shift"]
        data.clip_start, data.clip_end = 0.01, 1000.0
        obj = bpy.data.objects.new(cam["name"], data)
        obj.matrix_world = mathutils.Matrix(cam["matrix_world"])
        obj["dome_calib_K"] = [v for row in cam["K"] for v in row]
        obj["dome_calib_dist"] = cam["dist"]
        collection.objects.link(obj)
        if i == 0:
            scene = first_scene
            scene.name = cam["name"]
        else:
            scene = bpy.data.scenes.new(cam["name"])
            scene.collection.children.link(collection)
        scene.camera = obj
        render = scene.render
        render.resolution_x, render.resolution_y = cam["resolution"]
        render.resolution_percentage = 100
        render.pixel_aspect_x, render.pixel_aspect_y = cam["pixel_aspect"]
    return collection


build()
if "--" in sys.argv and sys.argv[sys.argv.index("--") + 1:]:
    bpy.ops.wm.save_as_mainfile(filepath=sys.argv[sys.argv.index("--") + 1])
'''


def write(cams: list[ForeignCamera], path: Path, unit: str, options: object = None) -> Written:
    """Write the script (``cams`` already in the z-up world, metres)."""
    data = [blender_camera(c) for c in cams]
    path.write_text(_SCRIPT.format(count=len(cams), data=repr(json.dumps(data))), encoding="utf-8")
    shifts = {c.name: corner_shift_px(c, np.zeros(5)) for c in cams if np.any(c.dist != 0)}
    return Written(dropped=[dropped_terms_line(shifts, "lens distortion (Blender's camera is a pinhole)")]
                   if shifts else [], corner_shift_px=shifts)
