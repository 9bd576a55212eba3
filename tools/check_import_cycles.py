"""Import cycles between the project's modules: every strongly connected component of the graph.

Every ``import`` and ``from ... import`` counts, wherever it is (module level, inside a
function, under ``TYPE_CHECKING``): a function-local import hides a cycle, it does not break
it. A cycle is broken by moving what both sides need to the module that should own it.

Usage: ``python tools/check_import_cycles.py [SRC]`` (default ``src``): prints one line per
cycle (its modules, sorted) and exits with 1 if there is any. ``test/test_architecture.py``
asserts there is none.
"""

from __future__ import annotations

import argparse
import ast
from pathlib import Path
import sys

__all__ = ['import_graph', 'import_cycles', 'main']


def _modules(src: Path) -> dict[str, Path]:
    """Dotted module name -> file, for every package ``src/PKG/PKG/**.py`` (not tests)."""
    mods = {}
    for path in sorted(src.glob('*/*/**/*.py')):
        rel = path.relative_to(src).parts[1:]            # drop the ament package folder
        if any(part in ('test', 'tests') for part in rel):
            continue
        name = '.'.join(rel)[:-3]
        mods[name.removesuffix('.__init__')] = path
    return mods


def import_graph(src: Path) -> dict[str, set[str]]:
    """Which project modules each project module imports (any import statement anywhere)."""
    mods = _modules(src)
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for name, path in mods.items():
        is_pkg = path.name == '__init__.py'
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'), str(path))):
            if isinstance(node, ast.ImportFrom):
                base = node.module or ''
                if node.level:
                    pkg = name if is_pkg else name.rsplit('.', 1)[0]
                    for _ in range(node.level - 1):
                        pkg = pkg.rsplit('.', 1)[0]
                    base = f'{pkg}.{base}' if base else pkg
                for alias in node.names:
                    for cand in (f'{base}.{alias.name}', base):
                        if cand in mods:
                            graph[name].add(cand)
                            break
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name in mods:
                        graph[name].add(alias.name)
    for name in graph:
        graph[name].discard(name)
    return graph


def import_cycles(src: Path) -> list[list[str]]:
    """The strongly connected components of :func:`import_graph` with more than one module
    (Tarjan's algorithm, iterative), each sorted, in order of their first module."""
    graph = import_graph(src)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        found.append(sorted(comp))
    return sorted(found)


def main(args: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('src', nargs='?', type=Path, default=Path('src'),
                        help='the folder of the ament packages (default: src)')
    ns = parser.parse_args(args)
    cycles = import_cycles(ns.src)
    for comp in cycles:
        print(comp)
    print(f'{len(cycles)} import cycles in {ns.src}', file=sys.stderr)
    return 1 if cycles else 0


if __name__ == '__main__':
    sys.exit(main())
