"""Where View's *not visible* policy drives the Husky: stuck behind it, where no module looks.

    python bench/husky_not_visible.py results/bench_robots/husky-view-seed1/run/checkpoint.npz
                                      [--poses 6] [--seed 5]

The View module's policy in its *not visible* state (paper III-C: the feature after the RBFs,
``b = e_n``, whatever else the robot senses; with ``view.lost_side``, which the Husky's forward
camera turns on, the first of three: *not yet seen* in the episode) is a Gaussian over the
wheel speeds with the mean ``v_max W[:, n_theta n_dist]`` (v_max, the module's speed limit at
the Husky's size: 1 m/s) and the std ``sigma`` of the checkpoint. This drives the Husky world
(``husky_world.world``, no ROS) with that policy from ``--poses`` random free poses, a
decision every 0.5 s for 45 s, and counts the decisions in which the robot is stuck: commanded
over 0.3 m/s, it moves less than 5 cm. Also printed: the lidar's nearest return at the end,
all around (the profile's ``episode.collision_sectors`` behind the robot count a collision
below 0.65 m from the centre).
"""

from __future__ import annotations

import argparse
import math

import numpy as np


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('checkpoint', help="a View run's checkpoint.npz (clis run --out)")
    p.add_argument('--poses', type=int, default=6)
    p.add_argument('--seed', type=int, default=5)
    args = p.parse_args()
    from clis_base.params import ConfigError
    from clis_learner.core.config import load_clis_params
    from cr_sim.core.profile import load_profile
    from husky_world.world import HuskyWorld, HuskyWorldParams
    z = np.load(args.checkpoint)
    _, view = load_clis_params().module('view')
    W = z['view.W'] * 1.0                           # noqa: N806 - x v_max = 1 m/s at its size
    mean = W[:, view.n_theta * view.n_dist]         # not visible (not yet seen)
    if W.shape[1] == view.n_theta * view.n_dist + 3:
        print(f'last seen on the left: mean wheels {np.round(W[:, -2], 3).tolist()} m/s, on '
              f'the right: {np.round(W[:, -1], 3).tolist()} m/s')
    sigma = float(np.asarray(z['view.sigma']).ravel()[0])
    body = load_profile('husky').body
    rng = np.random.default_rng(args.seed)
    print(f'not visible: mean wheels {np.round(mean, 3).tolist()} m/s, sigma {sigma:.3f} m/s')
    shares = []
    for k in range(args.poses):
        while True:
            x, y = rng.uniform(-4.4, 4.4, 2)
            yaw = rng.uniform(-math.pi, math.pi)
            try:
                world = HuskyWorld(HuskyWorldParams(width=16, height=16, start='', x=float(x),
                                                    y=float(y), yaw=float(yaw)))
                break
            except ConfigError:                     # no room for the robot there
                continue
        with world:
            stuck, before = 0, np.array(world.pose()[:2])
            for _ in range(90):
                left, right = np.clip(mean + rng.normal(0.0, sigma, 2), -body.v_max,
                                      body.v_max)
                v, omega = (left + right) / 2, (right - left) / body.wheel_base
                world.set_command(float(v), float(np.clip(omega, -body.omega_max,
                                                          body.omega_max)))
                world.step(120)                     # 0.5 s at 240 Hz
                after = np.array(world.pose()[:2])
                stuck += abs(v) > 0.3 and np.linalg.norm(after - before) < 0.05
                before = after
            shares.append(stuck / 90)
            print(f'pose {k}: from ({x:.1f}, {y:.1f}) to ({after[0]:.1f}, {after[1]:.1f}): '
                  f"stuck in {100 * stuck / 90:.0f}% of the decisions, the lidar's nearest "
                  f'return {float(np.nanmin(world.scan())):.2f} m')
    print(f'stuck in {100 * min(shares):.0f}-{100 * max(shares):.0f}% of the decisions '
          f'(mean {100 * np.mean(shares):.0f}%)')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
