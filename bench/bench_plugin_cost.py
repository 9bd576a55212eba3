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
from pathlib import Path
import re
import sys
import time
import timeit
import types

from clis_base.params import build
from clis_modules.core.decider import Decider, Percept
from clis_modules.core.modules import arena_map, build_module, load_module_params
from cr_sim.core.arena import load_arena
import numpy as np

DOC = Path(__file__).resolve().parent.parent / 'docs' / 'modules.md'


def documented_plugin() -> tuple[type, type]:
    """``(FrontIr, FrontIrParams)``: the code block ``# clis_frontir.py`` of docs/modules.md,
    run as it is written there."""
    for block in re.findall(r'```\w*\n(.*?)```', DOC.read_text(encoding='utf-8'), re.S):
        if block.startswith('# clis_frontir.py'):
            module = types.ModuleType('clis_frontir')
            sys.modules[module.__name__] = module           # for its dataclasses
            exec(compile(block, str(DOC), 'exec'), module.__dict__)      # noqa: S102
            return module.FrontIr, module.FrontIrParams
    raise SystemExit(f'{DOC} has no code block # clis_frontir.py')


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
    FrontIr, FrontIrParams = documented_plugin()       # noqa: N806
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
