#!/usr/bin/env python3
"""The peer of `s2r bench reconstruct`: Open3D's ScalableTSDFVolume and
marching cubes on the same depth frames, poses and voxel size.

Reads a job (JSON) written by the bench:
  {"voxel": m, "trunc": m, "depth_scale": counts per metre, "depth_trunc": m,
   "out": vertices.xyz, "frames": [{"depth": png, "width", "height", "fx", "fy", "cx", "cy",
   "camera_from_world": [16 numbers, row-major]}]}
and prints one JSON line: seconds per step, vertex and triangle counts.
Needs python3-open3d (Debian 12: 0.16)."""
import json
import sys
import time

import numpy as np
import open3d as o3d


def main() -> int:
    if len(sys.argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    with open(sys.argv[1]) as f:
        job = json.load(f)
    t0 = time.perf_counter()
    frames = []
    for fr in job["frames"]:
        depth = o3d.io.read_image(fr["depth"])
        color = o3d.geometry.Image(np.zeros((fr["height"], fr["width"], 3), dtype=np.uint8))
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            color, depth, depth_scale=job["depth_scale"], depth_trunc=job["depth_trunc"],
            convert_rgb_to_intensity=False)
        intr = o3d.camera.PinholeCameraIntrinsic(fr["width"], fr["height"], fr["fx"], fr["fy"], fr["cx"], fr["cy"])
        frames.append((rgbd, intr, np.array(fr["camera_from_world"], dtype=np.float64).reshape(4, 4)))
    t1 = time.perf_counter()
    volume = o3d.pipelines.integration.ScalableTSDFVolume(
        voxel_length=job["voxel"], sdf_trunc=job["trunc"],
        color_type=o3d.pipelines.integration.TSDFVolumeColorType.NoColor)
    for rgbd, intr, extr in frames:
        volume.integrate(rgbd, intr, extr)
    t2 = time.perf_counter()
    mesh = volume.extract_triangle_mesh()
    t3 = time.perf_counter()
    # Vertices as plain text (x y z per line): the bench measures their distance to the true surface.
    np.savetxt(job["out"], np.asarray(mesh.vertices, dtype=np.float64), fmt="%.7g")
    print(json.dumps({"seconds_load": t1 - t0, "seconds_integrate": t2 - t1, "seconds_mesh": t3 - t2,
                      "seconds": t3 - t0, "vertices": len(mesh.vertices), "triangles": len(mesh.triangles),
                      "open3d": o3d.__version__}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
