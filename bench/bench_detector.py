#!/usr/bin/env python3
"""Speed of the colour-blob detector: ``Detector.frame`` against the whole-image reference.

``Detector.frame`` (:mod:`clis_modules.core.detector`, the core of the ``detector`` node) runs
:func:`clis_modules.core.blobs.detect`, which computes ``hsv`` only on the pixels passing an
8-bit prefilter (``candidates``) and labels only within the box of each target's matches
(``target_pixels``). The reference is the plain path (every pixel through ``hsv``), written
out here (:func:`whole_image_reference`): ``hsv()`` on the whole image, ``ColourRange.mask`` per
target, ``scipy.ndimage.label`` on each whole mask, then the same blob, bearing and width.

Per robot profile and image size, ms per frame (wall time, median and 90th percentile) of
both over ``--frames`` frames, cycling through ``--poses`` different images, the two
alternating frame by frame:

* ``cr`` (the panoramic strip, 360 x 40) and ``turtlebot4`` (pinhole, 250 x 250): images of
  the arena (``config/arena.yaml``) by ``cr_sim.core.render`` from random free poses;
* ``husky`` (pinhole, 320 x 240 as its profile, and 160 x 120): PyBullet images of the
  ``husky_world`` example, the robot driving a circle, a frame a second; the detector reads
  them with the world's intrinsics (as the node does from ``camera_info``).

Every timed frame is also checked: the reference's masks equal ``target_masks`` and its blobs
equal the frame's (an ``AssertionError`` otherwise), so this benchmark guards the equality.

    python bench/bench_detector.py [--frames 200] [--poses 20] [--seed 0] [--json FILE]
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
import json
import math
import os
from pathlib import Path
import sys
import time

from clis_modules.core.blobs import (
    Blob,
    bearings,
    blob_of,
    hsv,
    target_masks,
    widths,
)
from clis_modules.core.detector import Detector
from clis_modules.detector_node import detector_of
from cr_sim.core.arena import load_arena
from cr_sim.core.camera import CameraModel
from cr_sim.core.profile import load_profile
from cr_sim.core.render import Scene, render
import numpy as np

CLEARANCE = 0.1                             # [m] a random pose's disc that must be free
ENCODING = 'rgb8'


def whole_image_reference(image: np.ndarray, camera: CameraModel, detector: Detector
                          ) -> tuple[list[np.ndarray], dict[str, Blob], np.ndarray, np.ndarray]:
    """The whole-image reference: ``hsv`` of every pixel, each target's ``ColourRange.mask``
    of the whole image, its blob from the whole mask (:func:`~clis_modules.core.blobs.blob_of`:
    ``ndimage.label`` of the whole image, the seam merged on a strip, the largest component),
    without the prefilter and the boxes of :func:`~clis_modules.core.blobs.detect`.

    Returns
    -------
    masks, blobs, bearings, widths
        The masks per target (for the equality check), the blobs, and the bearings and widths
        in the order of the targets.
    """
    params = detector.params
    h, s, v = hsv(image, ENCODING)
    masks, blobs = [], {}
    for name, rng in params.targets:
        mask = rng.mask(h, s, v)
        masks.append(mask)
        blobs[name] = blob_of(mask, camera, params.min_area)
    return masks, blobs, bearings(blobs, detector.names), widths(blobs, detector.names)


def same_blob(a: Blob, b: Blob) -> bool:
    """Field by field, NaN equal to NaN."""
    return all(x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y))
               for x, y in zip((a.seen, a.bearing, a.area, a.width, a.column, a.box),
                               (b.seen, b.bearing, b.area, b.width, b.column, b.box)))


def rendered_images(profile: str, poses: int, seed: int) -> tuple[Detector, list[np.ndarray]]:
    """The profile's detector and ``poses`` images of the arena rendered through its nominal
    camera from random free poses."""
    detector = detector_of(load_profile(profile))
    arena = load_arena(None)
    scene = Scene.from_arena(arena)
    rng = np.random.default_rng(seed)
    x0, y0, x1, y1 = arena.bounds
    images = []
    while len(images) < poses:
        x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
        if arena.gap(x, y, CLEARANCE) < 0.0:
            continue
        images.append(render(scene, detector.nominal, (x, y, rng.uniform(-math.pi, math.pi))))
    return detector, images


def husky_images(width: int, height: int, poses: int) -> tuple[Detector, list[np.ndarray]]:
    """The Husky's detector (with the world's intrinsics) and ``poses`` PyBullet images, one a
    second of sim time while the robot drives a circle from start A."""
    from husky_world.world import HuskyWorld, HuskyWorldParams
    detector = detector_of(load_profile('husky'))
    images = []
    with HuskyWorld(HuskyWorldParams(width=width, height=height)) as world:
        k = world.intrinsics
        detector.set_intrinsics(k.width, k.height,
                                (k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0))
        for _ in range(poses):
            world.set_command(0.4, 0.6)
            world.step(240)
            images.append(world.image())
    return detector, images


def cases(poses: int, seed: int) -> Iterator[tuple[str, Detector, list[np.ndarray]]]:
    """``(label, detector, images)`` per profile and image size."""
    for profile in ('cr', 'turtlebot4'):
        detector, images = rendered_images(profile, poses, seed)
        h, w = images[0].shape[:2]
        yield f'{profile} {w}x{h}', detector, images
    for w, h in ((320, 240), (160, 120)):
        detector, images = husky_images(w, h, poses)
        yield f'husky {w}x{h}', detector, images


def measure(detector: Detector, images: list[np.ndarray], frames: int) -> dict:
    """ms per frame of ``Detector.frame`` and of the reference, alternating, ``frames`` each
    (after a warm-up pass over the images); every timed frame checked for equality."""
    for image in images:                                    # warm-up (caches, allocator)
        detector.frame(image, ENCODING)
        whole_image_reference(image, detector.camera(image.shape[1], image.shape[0]),
                              detector)
    new, ref = np.empty(frames), np.empty(frames)
    seen = 0
    for i in range(frames):
        image = images[i % len(images)]
        t0 = time.perf_counter()
        det = detector.frame(image, ENCODING)
        t1 = time.perf_counter()
        camera = detector.camera(image.shape[1], image.shape[0])
        masks, blobs, _, _ = whole_image_reference(image, camera, detector)
        t2 = time.perf_counter()
        new[i], ref[i] = 1e3 * (t1 - t0), 1e3 * (t2 - t1)
        expected = target_masks(image, ENCODING, detector.params)
        for (name, _), got, want in zip(detector.params.targets, masks, expected):
            assert np.array_equal(got, want), f'frame {i}: {name}: masks differ'
            assert same_blob(blobs[name], det.blobs[name]), \
                f'frame {i}: {name}: {blobs[name]} != {det.blobs[name]}'
        seen += sum(b.seen for b in det.blobs.values())
    h, w = images[0].shape[:2]
    out = {'width': w, 'height': h, 'frames': frames, 'images': len(images),
           'targets_seen_per_frame': seen / frames}
    for key, ms in (('frame', new), ('reference', ref)):
        out[key] = {'median_ms': float(np.median(ms)), 'p90_ms': float(np.percentile(ms, 90))}
    out['speedup'] = out['reference']['median_ms'] / out['frame']['median_ms']
    return out


def machine_info() -> dict:
    """The machine as ``run_all`` reports it, and the load average now."""
    from run_all import machine  # bench/, the script's folder, is on sys.path
    return {**machine(), 'load_average': [round(x, 2) for x in os.getloadavg()]}


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark, print a table, optionally write JSON."""
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--frames', type=int, default=200,
                    help='timed frames per profile and size (each path)')
    ap.add_argument('--poses', type=int, default=20, help='different images, cycled')
    ap.add_argument('--seed', type=int, default=0, help='of the rendered poses')
    ap.add_argument('--json', metavar='FILE', help='write the results as JSON')
    args = ap.parse_args(argv)

    load0 = os.getloadavg()[0]
    results = {}
    for label, detector, images in cases(args.poses, args.seed):
        results[label] = measure(detector, images, args.frames)
    info = machine_info()
    info['load_average_at_start'] = round(load0, 2)

    print(f'blob detector benchmark  ({info["date"]}; {info["cpu"]}, {info["cores"]} CPUs, '
          f'{info["platform"]}; Python {info["python"]}, numpy {info["numpy"]}, '
          f'scipy {info["scipy"]}; load average {load0:.2f} at start, '
          f'{info["load_average"][0]:.2f} at end)')
    print(f'{args.frames} frames per row, {args.poses} images cycled; ms per frame, wall time')
    print(f'{"profile, size":<22} {"frame p50":>9} {"p90":>7} {"reference p50":>13} '
          f'{"p90":>7} {"speed-up":>8} {"seen":>5}')
    for label, r in results.items():
        f, ref = r['frame'], r['reference']
        print(f'{label:<22} {f["median_ms"]:>9.3f} {f["p90_ms"]:>7.3f} '
              f'{ref["median_ms"]:>13.3f} {ref["p90_ms"]:>7.3f} {r["speedup"]:>7.1f}x '
              f'{r["targets_seen_per_frame"]:>5.1f}')
    print('seen: targets seen per frame. Every timed frame checked: the reference masks equal '
          'target_masks, its blobs equal the frame blobs.')
    if args.json:
        rows = [{'measure': f'blob detector, {label}: Detector.frame | whole-image reference '
                            '(hsv of every pixel, mask, label), ms per frame p50 / p90; '
                            'speed-up of the median',
                 'value': f'{r["frame"]["median_ms"]:.2f} / {r["frame"]["p90_ms"]:.2f} | '
                          f'{r["reference"]["median_ms"]:.2f} / {r["reference"]["p90_ms"]:.2f};'
                          f' {r["speedup"]:.1f}x',
                 'goal': ''} for label, r in results.items()]
        out = {'machine': info, 'config': {'frames': args.frames, 'poses': args.poses,
                                           'seed': args.seed},
               'results': results, 'rows': rows}
        Path(args.json).write_text(json.dumps(out, indent=2) + '\n', encoding='utf-8')
        print(f'wrote {args.json}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
