#!/usr/bin/env python3
"""What a module plug-in written in plain Python costs per decision, against the built-in view
module: the same :class:`~clis_modules.core.decider.Decider` path (features, the policy (10),
the value (1)(2), the proposal) runs both; only the feature function differs.

The external plug-in is the one of docs/modules.md and ``test/test_plugin_package.py`` (the
bearing's RBFs and the front IR rays, numpy in Python: ``np.min`` and ``np.concatenate``
around an :class:`~clis_modules.core.features.RbfGrid`), built here without installing it.
CPU time per call, best of ``--repeats``.

    python bench/bench_plugin_cost.py [--calls 20000] [--repeats 5] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
import time
import timeit

from clis_modules.core.decider import Decider, Percept
from clis_modules.core.features import RbfGrid, uniform_centers
from clis_modules.core.modules import (
    PolicyParams,
    ValueParams,
    arena_map,
    build_module,
    load_module_params,
)
from clis_modules.core.plugin import FeatureModel, ModulePlugin
from cr_sim.core.arena import load_arena
from cr_sim.core.params import build, dataclass, param
import numpy as np


@dataclass(frozen=True)
class FrontIrParams:
    period: float = param(0.01, 60.0, doc='decision period [s]')
    n_theta: int = param(1, 100, doc='RBF centres over the bearing')
    value: ValueParams = param(doc='value (1)(2), learned by (8)')
    policy: PolicyParams = param(doc='policy (10), learned by (9)')


class FrontIr(ModulePlugin):
    """docs/modules.md's example: the front IR rays and the destination's bearing."""

    Params = FrontIrParams
    sensors = ('camera', 'ir')
    learned = True
    defaults = {'period': 0.4, 'n_theta': 5, 'value': {'alpha': 0.1, 'v_init': 0.0},
                'policy': {'alpha': 0.5, 'sigma': 0.1, 'learn_sigma': False,
                           'sigma_min': 0.02, 'sigma_max': 0.5, 'alpha_sigma': 0.0}}

    def model(self, prm, ctx):
        grid = RbfGrid([uniform_centers(-math.pi, math.pi, prm.n_theta, True)],
                       [(2 * math.pi / prm.n_theta) ** 2], [True], normalize=True)

        def features(p):
            front = 1.0 if p.ir is None else float(np.min(p.ir[2:5])) / 0.5
            return np.concatenate([grid.at(p.dest_bearing), [front]])
        return FeatureModel(grid.n + 1, features)


class _Zeros:
    """The two normals of a proposal (their values do not change the cost)."""

    def standard_normal(self, n: int) -> np.ndarray:
        return np.zeros(n)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--calls', type=int, default=20000)
    ap.add_argument('--repeats', type=int, default=5)
    ap.add_argument('--json', metavar='FILE')
    args = ap.parse_args()
    landmarks, floor, boxes = arena_map(load_arena())
    params = load_module_params()
    plugin = FrontIr()
    plugin.name = 'frontir'
    external = build_module('frontir', plugin, build(FrontIrParams, dict(plugin.defaults)),
                            params.common, None, landmarks, floor, boxes)
    view_plugin, view_prm = params.module('view')
    view = build_module('view', view_plugin, view_prm, params.common, None, landmarks, floor,
                        boxes)
    percept = Percept(0.0, 0.3, 0.4, np.array([0.1, -1.0, 2.0, np.nan]), np.full(7, 0.4),
                      np.array([0.1, 0.1]))
    rows, results = [], {}
    for label, module in (('view (built-in)', view),
                          ('frontir (external, plain Python)', external)):
        decider = Decider(module, _Zeros(), 0.1)

        def per_call(fn) -> float:
            return min(timeit.repeat(fn, number=args.calls, repeat=args.repeats,
                                     timer=time.process_time)) / args.calls

        feats = per_call(lambda m=module: m.feature_fn(percept))
        whole = per_call(lambda d=decider: d.decide(percept))
        results[module.name] = {'features_s': feats, 'decision_s': whole}
        print(f'{label:34s} features {1e6 * feats:5.2f} us, whole decision {1e6 * whole:5.2f} us')
        rows.append({'measure': f'one decision of {label}: features / whole [us]',
                     'value': f'{1e6 * feats:.2f} / {1e6 * whole:.2f}', 'goal': ''})
    if args.json:
        Path(args.json).write_text(json.dumps({'results': results, 'rows': rows}, indent=2))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
