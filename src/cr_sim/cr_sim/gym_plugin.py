"""Registration of the Gymnasium environments ``CRNav-v0`` (docs/gym.md); standard library only.

:func:`register_envs` registers ``CRNav-v0`` with ``gymnasium.register``: the single robot
:class:`cr_sim.gym_env.CRNavEnv` (``gymnasium.make``) and the many-robot
:class:`cr_sim.gym_env.CRNavVectorEnv` (``gymnasium.make_vec``), both by their import path, so
that registering imports neither (nor numpy). It runs

* when :mod:`cr_sim.gym_env` is imported (registration at import, Gymnasium 1.x's way:
  ``gymnasium.make('cr_sim.gym_env:CRNav-v0')`` imports it first);
* from the ``gymnasium.envs`` entry point of the cr_sim distribution (setup.py), which
  Gymnasium 0.26 to 0.29 loaded at ``import gymnasium`` (1.0 dropped that plugin loading);
* when ``gymnasium`` is imported in any interpreter of the project's venv: ``make setup`` copies
  this file into the venv's site-packages as ``_cr_sim_gym_hook.py`` with a ``.pth`` line that
  calls :func:`install_hook` at interpreter start-up. So ``gymnasium.make('CRNav-v0')`` works
  in a fresh interpreter, with no import of cr_sim first, and a training script
  (Stable-Baselines3, CleanRL) runs unchanged.
"""

from __future__ import annotations

import sys

# (nothing else at import: the venv's copy is imported at every interpreter start-up)
__all__ = ['ENV_ID', 'ENTRY_POINT', 'VECTOR_ENTRY_POINT', 'register_envs', 'install_hook']

ENV_ID = 'CRNav-v0'
ENTRY_POINT = 'cr_sim.gym_env:CRNavEnv'
VECTOR_ENTRY_POINT = 'cr_sim.gym_env:CRNavVectorEnv'


def register_envs() -> None:
    """Register ``CRNav-v0`` (once; a second call does nothing).

    No ``max_episode_steps``: the environment truncates an episode itself at the simulator's
    ``episode.time_limit`` (60 s, 1200 steps); ``gymnasium.make('CRNav-v0',
    max_episode_steps=N)`` adds Gymnasium's ``TimeLimit`` as for any environment.
    """
    from gymnasium.envs.registration import register, registry
    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point=ENTRY_POINT, vector_entry_point=VECTOR_ENTRY_POINT)


class _GymnasiumHook:
    """A meta path finder (``importlib.abc.MetaPathFinder``'s protocol) that calls
    :func:`register_envs` right after ``gymnasium`` has been imported, once."""

    def find_spec(self, name: str, path: object = None, target: object = None) -> object:
        if name != 'gymnasium':
            return None
        if self in sys.meta_path:
            sys.meta_path.remove(self)
        import importlib.util
        spec = importlib.util.find_spec(name)              # the real one, by the other finders
        if spec is None or spec.loader is None or not hasattr(spec.loader, 'exec_module'):
            return spec
        exec_module = spec.loader.exec_module

        def exec_and_register(module: object) -> None:
            exec_module(module)
            try:
                register_envs()
            except Exception as exc:                       # noqa: BLE001 never break gymnasium
                import warnings
                warnings.warn(f'{ENV_ID} not registered: {exc!r}', stacklevel=2)

        spec.loader.exec_module = exec_and_register        # this spec's loader only
        return spec


def install_hook() -> None:
    """Register ``CRNav-v0`` when ``gymnasium`` is imported (now, if it already is)."""
    if 'gymnasium' in sys.modules:
        register_envs()
    elif not any(isinstance(f, _GymnasiumHook) for f in sys.meta_path):
        sys.meta_path.insert(0, _GymnasiumHook())
