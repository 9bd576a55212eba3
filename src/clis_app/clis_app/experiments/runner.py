"""Headless runner: a discrete-event loop that drives the simulator, the modules, the arbiter and
the learner at the simulator tick, as fast as the CPU allows, reproducibly per seed.

It is one of the two schedulers of the same cores (the other is the ROS node graph): each module
decides through its :class:`~clis_modules.core.decider.Decider`, the arbiter selects through the
:class:`~clis_modules.core.arbiter.Selector`, and the learner's
:class:`~clis_learner.core.memory.StreamBuffer` turns the timestamped records into the episode
that :class:`~clis_learner.core.learner.Learner` learns from, assembled by the same
:class:`~clis_learner.core.intake.EpisodeStream` as the learner node's and ``clis learn``'s.
Only where the inputs come from and when differs: here every record is made by this loop and
fed to it directly, in the nodes it arrives as a message.

Time (docs/design.md §6): the simulator advances in ticks of ``episode.dt`` (50 ms). Module ``i``
decides at every tick ``k`` with ``k mod n_i = 0``, ``n_i = tau_i / dt`` (5, 10, 24 ticks for
250/500/1200 ms in **Async**; all 24 in **Sync**), reading the sensors of that instant. The
robot executes the command in force, the acting module's proposal clipped to that module's
speed limit ``v_max,i = min(1.3, d_react / tau_i)`` (docs/design.md §3); the proposal itself (not
clipped) is what the learner's densities see. The reward of a tick is stamped at its end.

Selection (3): ``arbiter.selection = episode`` draws the acting module once, from the values of
the start state (what (4)-(6) assume); ``decision`` redraws at every tick at which any module
decides.

Modules with a ``motion`` hook (the place module's localization): the executed wheel velocities
of every tick are composed into one displacement in the robot frame (odometry), applied at the
module's next decision by that hook, followed by its ``sense`` hook (paper III-D).

After each learning episode the learner trains every module from it (eqs. 6-9, 11).
"""

from __future__ import annotations

from collections.abc import Callable
import dataclasses
from dataclasses import asdict
import math
import time
from typing import Any

from clis_base.instants import DecisionClock
from clis_learner.core.checkpoint import save_checkpoint
from clis_learner.core.config import ClisParams, params_hash
from clis_learner.core.guard import Divergence
from clis_learner.core.intake import EpisodeStream
from clis_modules.core.arbiter import Selector, selection_probs
from clis_modules.core.decider import Decider, Percept
from clis_modules.core.draws import AgentStream, module_draws, selection_draws
from clis_modules.core.modules import (
    CONDITIONS,
    ModuleCore,
    arena_map,
    make_modules,
)
from clis_modules.core.plugin import solo_condition
from cr_sim.core.arena import Arena
from cr_sim.core.sim import SimParams, Simulator
from cr_sim.core.starts import draw_start
import numpy as np

from clis_app.experiments.jobs import JobResult, JobSpec, arena_dict, result_path  # noqa: F401

__all__ = ['CONDITIONS', 'Agent', 'run_episode', 'place_selection_map', 'JobSpec', 'JobResult',
           'run_job', 'warm_up']


class Agent:
    """The CLIS modules of one condition, with their deciders, selector and learner.

    Parameters
    ----------
    params : ClisParams
    condition : str
        ``TIMING:MODULE+MODULE...``, or ``innate``, ``view``, ``place``, ``sync``, ``async``.
    arena : Arena
        Landmarks and obstacles (the place module's localization grid).
    rng : np.random.Generator
        The agent stream: draws the selections and the modules' actions, in the order of
        :class:`~clis_modules.core.draws.AgentStream` (the graph's nodes replay it).
    wheel_base : float
        Of the robot [m]: wheel velocities to odometry.
    """

    def __init__(self, params: ClisParams, condition: str, arena: Arena,
                 rng: np.random.Generator, wheel_base: float) -> None:
        self.params = params
        self.condition = condition
        self.modules: list[ModuleCore] = make_modules(params, condition, *arena_map(arena))
        self.names = [m.name for m in self.modules]
        if params.arbiter.bonus > 0.0:
            for m in self.modules:       # the exploration bonus's selection counts C_i
                m.visits = np.zeros(m.n)
        self.gammas = np.array([m.gamma for m in self.modules])
        self.stream = AgentStream(rng, len(self.modules), params.arbiter.selection)
        self.deciders = [Decider(m, module_draws(self.stream, i), wheel_base)
                         for i, m in enumerate(self.modules)]
        self.selector = Selector(self.names, self.gammas, [m.v_max for m in self.modules],
                                 [m.period for m in self.modules], params.arbiter,
                                 params.common.beta, selection_draws(self.stream))
        #: the episode assembly (the learner node's): records in, rows and learning out
        self.episodes = EpisodeStream(self.modules, params, condition, 0, whole=True)
        self.learner = self.episodes.learner
        self.rng = rng
        #: the module whose state the place-selection map sets at each pose (an ``at_pose``
        #: hook: the place module), or None
        self.place = next((m for m in self.modules if m.at_pose is not None), None)

    def values(self, feats: list[np.ndarray]) -> np.ndarray:
        """``V_i(x)`` of every module at the given features, shape (N,)."""
        return np.array([m.value(b) for m, b in zip(self.modules, feats)])


def run_episode(sim: Simulator, agent: Agent, start: Any, heading: float | None,
                learn: bool = True) -> dict[str, Any]:
    """Run one episode from ``start``; learn from it unless ``learn`` is False.

    Returns
    -------
    dict
        One row (:func:`~clis_learner.core.episodes.episode_row`): outcome, who acted,
        selection probabilities and values at the start, and the learner's per-module
        diagnostics (``{key}_{module}``).
    """
    deciders, names = agent.deciders, agent.names
    selector, episodes = agent.selector, agent.episodes
    dt = sim.params.episode.dt
    stream = agent.stream
    if stream.clock is None or stream.clock.dt != dt:
        stream.clock = DecisionClock([d.module.period for d in deciders], dt)
    clock = stream.clock
    # the modules due at tick k are schedule[k % cycle] (cycle: the periods' common multiple)
    cycle, gaps = clock.cycle, clock.gaps
    schedule = [[deciders[i] for i in due] for due in clock.schedule]
    sim.reset(start=start, heading=heading)
    for d in deciders:
        d.reset()
    localizing = [d for d in deciders if d.tracks_motion]
    selector.begin_episode(0.0)
    # the exploration bonus (arbiter.bonus) in learning episodes only
    selector.explore_now = learn and selector.kappa > 0.0
    stream.begin_episode()
    episodes.start(0.0, 0, start if isinstance(start, str) else 'pose', dt)
    u_exec = np.zeros(2)
    # the acting module's features at the other modules' instants (learner.behaviour_state),
    # read only by the learner's replay: none for an episode it does not learn from
    observe = (learn and agent.params.learner.behaviour_state == 'resampled'
               and agent.params.learner.behaviour == 'acting' and len(deciders) > 1)
    k = 0
    while True:
        due = schedule[k % cycle]
        if due:
            t = k * dt
            # the sensors the modules read (Simulator.observe's values, no Observation made)
            percept = Percept(t, *sim.sense_all())
            stream.instant(k)                 # the draws of the instant (AgentStream)
            proposals = [d.decide(percept) for d in due]
            for p in proposals:
                episodes.proposal(p)
            cmd = selector.on_proposals(proposals, t)
            if cmd is not None:
                u_exec = cmd.u_exec
                if cmd.drawn:
                    episodes.selection(t, dict(zip(names, selector.probs)),
                                       dict(zip(names, selector.values)))
                if cmd.module >= 0:
                    episodes.action(cmd.t, cmd.u, names[cmd.module])
            acting = deciders[selector.acting] if observe and selector.acting >= 0 else None
            if acting is not None and acting not in due:
                # (6): the behaviour's state at this decision instant of another module
                episodes.observation(acting.name, t, acting.observe(percept))
        # the command held until the next decision, or up to a reward or the episode's end
        res, wheels = sim.hold(u_exec, gaps[k % cycle])
        k += res.steps
        if res.reward != 0.0:
            episodes.reward(k * dt, res.reward)        # stamped at the end of the tick
        for d in localizing:
            d.on_wheel_steps(wheels, dt)
        if res.done:
            break
    stream.end_episode(k)
    episodes.end(k * dt, 0, 'reached' if res.reached else 'timeout')
    return episodes.close(learn=learn).core


def place_selection_map(agent: Agent, sim: Simulator, resolution: float = 0.1) -> dict | None:
    """Pr(M_pl | x) of (3) on a grid of positions, heading to the destination (paper Fig. 4).

    The modules read the sensors at that pose; the one with an ``at_pose`` hook (the place
    module: its belief localized on the cell of the pose, the end-of-learning situation the
    figure shows) is put there first. Positions where the robot does not fit are NaN.

    Returns
    -------
    dict or None
        ``{'x': (nx,), 'y': (ny,), 'p': (ny, nx), 'modules': {name: (ny, nx)}}`` (``p``: the
        place module's; ``modules``: every module's Pr(i | x)); None without a place module or
        with one module only.
    """
    if agent.place is None or len(agent.modules) < 2:
        return None
    x0, y0, x1, y1 = sim.arena.bounds
    xs = np.arange(x0 + resolution / 2, x1, resolution)
    ys = np.arange(y0 + resolution / 2, y1, resolution)
    dest = sim.arena.destination
    i_place = agent.modules.index(agent.place)
    p_all = np.full((len(ys), len(xs), len(agent.modules)), np.nan)
    for iy, y in enumerate(ys):
        for ix, x in enumerate(xs):
            heading = math.atan2(dest.y - y, dest.x - x)
            try:
                obs = sim.reset(start=(x, y, heading))
            except ValueError:
                continue  # the robot does not fit here
            agent.place.at_pose(x, y, heading)
            percept = Percept.from_observation(obs.t, obs)
            feats = [m.features(percept) for m in agent.modules]
            arb = agent.params.arbiter
            probs = selection_probs(agent.values(feats), agent.gammas,
                                    agent.params.common.beta, None, arb.rule, arb.scale_min,
                                    arb.explore)
            p_all[iy, ix] = probs
    agent.place.reset()
    return {'x': xs.tolist(), 'y': ys.tolist(), 'p': p_all[:, :, i_place].tolist(),
            'modules': {m.name: p_all[:, :, k].tolist() for k, m in enumerate(agent.modules)}}


def run_job(spec: JobSpec, progress: Callable[[int, str], None] | None = None) -> JobResult:
    """Learn for ``spec.episodes`` episodes, then evaluate from every start point.

    Seeding: the simulator, the start draws and the agent have separate generators derived from
    the seed, so every condition sees the same sequence of start points for a given seed.
    """
    t0 = time.perf_counter()
    params, sim_params, arena = spec.load()
    sim = Simulator(arena, sim_params, np.random.default_rng([spec.seed, 0]))
    start_rng = np.random.default_rng([spec.seed, 1])
    agent = Agent(params, spec.condition, arena, np.random.default_rng([spec.seed, 2]),
                  sim_params.robot.wheel_base)
    base = {'label': spec.label, 'condition': spec.condition, 'seed': spec.seed}
    episodes, evals, eval_curve = [], [], []
    diverged: dict[str, int] = {}

    def evaluate_now(learned: int) -> None:
        rows = evaluate(agent, arena, sim_params, spec.seed, learned, spec.eval_episodes)
        eval_curve.append({'episode': learned, 'reached': int(sum(r['reached'] for r in rows)),
                           'n': len(rows), **{f'reached_{s}': int(sum(
                               r['reached'] for r in rows if r['start'] == s))
                               for s in arena.start_names}})

    if spec.eval_every > 0:
        evaluate_now(0)
    for ep in range(spec.episodes):
        start, heading = draw_start(spec.train_start, arena, start_rng)
        row = run_episode(sim, agent, start, heading, learn=True)
        episodes.append({**base, 'phase': 'train', 'episode': ep, **row})
        for d in Divergence.from_row(row, ep + 1):      # the guard: once per module
            diverged[d.module] = d.episode
            if progress is not None:
                progress(ep + 1, f'WARNING: {spec.label} seed {spec.seed}: {d.message()}')
        if spec.eval_every > 0 and (ep + 1) % spec.eval_every == 0:
            evaluate_now(ep + 1)
        if progress is not None and ((ep + 1) % 10 == 0 or ep + 1 == spec.episodes):
            recent = episodes[-spec.block:]
            progress(ep + 1, f'{spec.label} s{spec.seed} ep {ep + 1} '
                             f'succ {sum(r["reached"] for r in recent)}/{len(recent)}')
    for name in arena.start_names:
        for k in range(spec.eval_episodes):
            row = run_episode(sim, agent, name, None, learn=False)
            evals.append({**base, 'phase': 'eval', 'episode': k, **row})
    place_map = place_selection_map(agent, sim)
    solo = solo_evaluation(agent, params, arena, sim_params, spec) if spec.eval_every > 0 else {}
    ckpt = JobSpec(**asdict(spec)).result_path().with_suffix('.npz')
    save_checkpoint(ckpt, agent.modules, params_hash(params),
                    {'label': spec.label, 'seed': spec.seed, 'episodes': spec.episodes})
    final = {}
    last = episodes[-spec.block:]
    for key in ('reached', 'duration', 'collisions'):
        final[key] = float(np.mean([r[key] for r in last]))
    for name in agent.names:
        final[f'p_{name}'] = float(np.mean([r[f'p_{name}'] for r in last]))
        final[f'share_{name}'] = float(np.mean([r[f'share_{name}'] for r in last]))
        logc = [r.get(f'log10c_{name}', np.nan) for r in last]
        logc = [v for v in logc if np.isfinite(v)]
        final[f'median_log10c_{name}'] = float(np.median(logc)) if logc else math.nan
    return JobResult(spec=asdict(spec), modules=agent.names, block=spec.block,
                     episodes=episodes, evals=evals, place_map=place_map,
                     arena=arena_dict(arena), seconds=time.perf_counter() - t0,
                     final_diagnostics=final, params_hash=params_hash(params),
                     eval_curve=eval_curve, solo=solo, diverged=diverged)


class _SwappedRng:
    """Context: every random draw of ``agent`` (proposals, selections) comes from ``rng``
    inside the block, so evaluation episodes leave the learning run's random stream as it was
    (a run with periodic evaluation learns exactly as one without)."""

    def __init__(self, agent: Agent, rng: np.random.Generator) -> None:
        self.agent, self.rng = agent, rng

    def __enter__(self) -> None:
        self.saved = self.agent.stream.rng
        self.agent.stream.rng = self.rng

    def __exit__(self, *exc: Any) -> None:
        self.agent.stream.rng = self.saved


def evaluate(agent: Agent, arena: Arena, sim_params: SimParams, seed: int, point: int,
             per_start: int) -> list[dict[str, Any]]:
    """``per_start`` episodes from each start A-E with learning off (paper Fig. 2: the start
    positions "to evaluate performance during learning").

    The simulator and the agent's draws come from generators of ``(seed, 3, point)`` only:
    every condition with the same seed sees the same evaluation starts and sensor noise at the
    same point, and the learning run's own generators are not touched.

    Returns
    -------
    list of dict
        One row per episode (:func:`run_episode`) with its ``start``.
    """
    sim = Simulator(arena, sim_params, np.random.default_rng([seed, 3, point, 0]))
    rows = []
    with _SwappedRng(agent, np.random.default_rng([seed, 3, point, 1])):
        for name in arena.start_names:
            for _ in range(per_start):
                rows.append(run_episode(sim, agent, name, None, learn=False))
    return rows


def solo_evaluation(agent: Agent, params: ClisParams, arena: Arena, sim_params: SimParams,
                    spec: JobSpec) -> dict[str, dict[str, float]]:
    """The thesis measured directly: each learned module of a multi-module run, trained
    inside it, evaluated acting alone from A-E (learning off), as in its single-module
    condition (same period, speed limit and evaluation draws as :func:`evaluate` at the last
    point).

    Returns
    -------
    dict
        ``{module: {'reached': successes, 'n': episodes, 'duration': mean [s]}}``; empty for
        a single-module run.
    """
    if len(agent.modules) < 2:
        return {}
    out = {}
    for m in agent.modules:
        if not m.learned:
            continue
        solo = Agent(params, solo_condition(m.name), arena, np.random.default_rng(0),
                     sim_params.robot.wheel_base)
        solo.modules[0].w, solo.modules[0].W, solo.modules[0].sigma = m.w, m.W, m.sigma
        rows = evaluate(solo, arena, sim_params, spec.seed, spec.episodes, spec.eval_episodes)
        out[m.name] = {'reached': float(sum(r['reached'] for r in rows)), 'n': float(len(rows)),
                       'duration': float(np.mean([r['duration'] for r in rows]))}
    return out


def warm_up(spec: JobSpec) -> None:
    """Load the compiled kernels (numba, from its disk cache) in this process by running one
    short Async episode in ``spec``'s arena: worker processes forked afterwards inherit them
    instead of each loading them again (about 0.4 s per process)."""
    params, sim_params, arena = spec.load()
    sim_params = dataclasses.replace(sim_params, episode=dataclasses.replace(
        sim_params.episode, time_limit=2.5))
    sim = Simulator(arena, sim_params, np.random.default_rng(0))
    agent = Agent(params, 'async', arena, np.random.default_rng(0), sim_params.robot.wheel_base)
    run_episode(sim, agent, 'wander', None)
