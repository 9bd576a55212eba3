"""The live view's Foxglove layout, generated for a condition's modules (ROS-free).

The layout (docs/foxglove.md) is built with the ``foxglove.layouts`` model of the SDK from the
condition's module instances: the arena, the robot and its path, the belief grids the modules
publish, which module acts, Pr(i | x), the reward and the success rate. The shipped
``config/foxglove_layout.json`` is :func:`layout_json` of :data:`LAYOUT_CONDITION`; the live
view (:mod:`clis_app.live.foxglove_node`) writes its own condition's into a run's folder.
"""

from __future__ import annotations

import json
from typing import Any

__all__ = ['PATH_TOPIC', 'SUCCESS_TOPIC', 'LAYOUT_CONDITION', 'LAYOUT_FILE', 'GRID_TYPE',
           'layout_modules', 'layout', 'shown_topics', 'layout_json']

#: The robot's path and the success rate, channels the live view computes.
PATH_TOPIC = '/foxglove/path'
SUCCESS_TOPIC = '/foxglove/success'
#: The condition of the shipped layout, ``config/foxglove_layout.json``: the graph's default
#: (``graph.condition`` of ``config/graph.yaml``).
LAYOUT_CONDITION = 'async'
#: The layout of the live view's condition, written into a ``clis run``'s folder.
LAYOUT_FILE = 'foxglove_layout.json'
#: Message type of a belief grid a module publishes (a plug-in's ``topics``).
GRID_TYPE = 'nav_msgs/msg/OccupancyGrid'


def layout_modules(condition: str, clis: Any = None) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The module instances of ``condition`` in the order of ``arbiter/selection``'s
    ``position`` (Pr(i | x), the condition's order), and the belief grids they publish
    (``/NAME/TOPIC`` of each plug-in's ``topics`` of type :data:`GRID_TYPE`).

    Parameters
    ----------
    condition : str
    clis : ClisParams, optional
        Where the instances' plug-ins are found; None: ``config/clis.yaml``.
    """
    from clis_modules.core.plugin import parse_condition
    if clis is None:
        from clis_learner.core.config import load_clis_params
        clis = load_clis_params()
    modules = parse_condition(condition).modules
    beliefs = tuple(f'/{name}/{topic}' for name in modules
                    for topic, typ in clis.module(name)[0].topics.items() if typ == GRID_TYPE)
    return modules, beliefs


def layout(condition: str = LAYOUT_CONDITION, clis: Any = None) -> Any:
    """The Foxglove layout of ``condition``'s graph (docs/foxglove.md; ``clis`` as for
    :func:`layout_modules`), built with the ``foxglove.layouts`` model of the SDK: left, the
    arena with the robot and its path, and the belief grids its modules publish (the place
    module's; 3D panels, top view of the ``odom`` frame); right, which module acts, Pr(i | x)
    of each of its modules, the reward and the success rate over sim time.
    ``config/foxglove_layout.json`` is the layout of :data:`LAYOUT_CONDITION`."""
    import foxglove.layouts as fl
    modules, beliefs = layout_modules(condition, clis)

    def top_view(topics: dict[str, Any]) -> Any:
        return fl.ThreeDeeConfig(
            follow_tf='odom', fixed_frame='odom', follow_mode='follow-none',
            camera_state=fl.ThreeDeeCameraState(perspective=False, distance=6.0, phi=0.0,
                                                target=(0.0, 0.0, 0.0),
                                                target_offset=(0.0, 0.0, 0.0), theta_offset=0.0),
            topics=topics)

    arena = fl.BaseRendererRosMarkerTopicSettings(visible=True)
    scene = fl.ThreeDeePanel(title='Arena, robot and its path', config=top_view({
        '/arena': arena,
        '/markers': fl.BaseRendererRosMarkerTopicSettings(visible=True),
        '/odom': fl.BaseRendererPoseTopicSettings(visible=True, type='arrow',
                                                  arrow_scale=(0.15, 0.03, 0.03),
                                                  color='#1e5fffff'),
        PATH_TOPIC: fl.BaseRendererPosesTopicSettings(visible=True, type='line',
                                                       line_width=0.015,
                                                       gradient=('#1e5fff40', '#1e5fffff')),
    }))
    owners = [b.split('/')[1] for b in beliefs]
    belief = fl.ThreeDeePanel(
        title=(f"{owners[0].capitalize()} module's belief" if len(owners) == 1 else
               f"Beliefs of {', '.join(owners)}") + ' (most probable cell = 100)',
        config=top_view({
            **{b: fl.BaseRendererRosOccupancyGridTopicSettings(
                visible=True, color_mode='map', alpha=0.8, frame_locked=True) for b in beliefs},
            '/arena': arena}))

    def stamped(value: str, label: str) -> Any:
        return fl.PlotSeries(value=value, label=label, enabled=True,
                             timestamp_method='headerStamp')

    acting = fl.StateTransitionsPanel(title='Acting module', config=fl.StateTransitionsConfig(
        paths=[fl.StateTransitionsSeries(value='/arbiter/selection.header.frame_id',
                                         label='drawn by the arbiter',
                                         timestamp_method='headerStamp'),
               fl.StateTransitionsSeries(value='/arbiter/action.header.frame_id',
                                         label="in cmd_vel ('' = stop)",
                                         timestamp_method='headerStamp')]))
    probs = fl.PlotPanel(title='Pr(i | x) at each draw', config=fl.PlotConfig(
        paths=[stamped(f'/arbiter/selection.position[{k}]', f'Pr({m} | x)')
               for k, m in enumerate(modules)],
        min_y_value=0.0, max_y_value=1.0, show_legend=True))
    reward = fl.PlotPanel(title='Reward', config=fl.PlotConfig(
        paths=[stamped('/reward.vector.x', 'reward of the tick'),
               stamped('/reward.vector.y', 'episode return')], show_legend=True))
    success = fl.PlotPanel(title='Success rate', config=fl.PlotConfig(
        paths=[stamped(f'{SUCCESS_TOPIC}.vector.x', 'reached, share of the last block'),
               stamped(f'{SUCCESS_TOPIC}.vector.z', 'reached (this episode)')],
        min_y_value=0.0, max_y_value=1.0, show_legend=True))

    def split(direction: str, *items: tuple[float, Any]) -> Any:
        return fl.SplitContainer(direction=direction, items=[
            fl.SplitItem(proportion=p, content=c) for p, c in items])

    left = split('column', (0.6, scene), (0.4, belief)) if beliefs else scene
    return fl.Layout(content=split(
        'row',
        (0.55, left),
        (0.45, split('column', (0.2, acting), (0.3, probs), (0.25, reward), (0.25, success)))))


def shown_topics(layout: object) -> frozenset[str]:
    """The topics a Foxglove layout (the parsed JSON of ``config/foxglove_layout.json``)
    shows: its 3D panels' topics and the topics of its plotted message paths."""
    shown: set[str] = set()

    def walk(node: object) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                if k == 'topics' and isinstance(v, dict):
                    shown.update(v)
                elif k == 'value' and isinstance(v, str):
                    shown.add(v.split('.')[0])
                walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)
    walk(layout)
    return frozenset(shown)


def layout_json(condition: str = LAYOUT_CONDITION, clis: Any = None) -> str:
    """:func:`layout` as the text of a layout file (indented, one newline at the end): for
    :data:`LAYOUT_CONDITION`, ``config/foxglove_layout.json``."""
    return json.dumps(json.loads(layout(condition, clis).to_json()), indent=2) + '\n'
