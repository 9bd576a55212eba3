"""Every link in the documentation resolves, and so does every citation of it in the code.

* In every tracked Markdown file, each relative link or image ``[text](path#anchor)`` names a
  file or folder that exists, and its anchor (if any) is a heading of the target, by GitHub's
  anchor rules (lowercase; punctuation dropped; spaces to ``-``; ``-1``, ``-2`` for repeats).
* In every tracked text file (code, config, docs, Makefile, env.sh, requirements), each cited
  ``docs/NAME.md`` exists, each ``docs/NAME.md#anchor`` is a heading there, and each
  ``docs/design.md §n`` (also ``§2, 9`` and ``§1 and 3``) is a numbered section of
  docs/design.md (a heading ``## n. Title``).

Links inside code (fenced blocks and inline code spans) are examples, not links, and are not
checked; links with a scheme (``https:``, ``mailto:``) are left to the reader.
"""

from __future__ import annotations

from pathlib import Path
import re
import subprocess

import pytest

REPO = Path(__file__).resolve().parent.parent

#: ``[text](target)`` and ``![alt](target)``; the target stops at whitespace or ``)``.
LINK = re.compile(r'!?\[(?:[^\]\\]|\\.)*\]\(\s*<?([^)\s>]+)>?(?:\s+"[^"]*")?\s*\)')
#: ``[label]: target`` reference definitions.
REF_DEF = re.compile(r'^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$', re.M)
#: a cited docs file, with an optional anchor
DOCS_CITE = re.compile(r'(?<![\w/.])docs/([\w.-]+\.md)(#[\w-]+)?')
#: ``docs/design.md §2``, ``§2, 9``, ``§1 and 3``
SECTION_CITE = re.compile(r'docs/design\.md\s*§\s*(\d+(?:(?:\s*,\s*|\s+and\s+)\d+)*)')
HEADING = re.compile(r'^ {0,3}(#{1,6})[ \t]+(.*?)[ \t#]*$')
HTML_ANCHOR = re.compile(r'<a\s+(?:name|id)="([^"]+)"', re.I)
NUMBERED = re.compile(r'^(\d+)\.\s')
TEXT_SUFFIXES = {'.py', '.md', '.yaml', '.yml', '.xml', '.txt', '.cfg', '.sh', '.toml', '.ini',
                 '.json', ''}


def tracked(repo: Path) -> list[Path]:
    """The repository's tracked files (every file under ``repo`` when it is not a git tree)."""
    try:
        out = subprocess.run(['git', 'ls-files', '-z'], cwd=repo, capture_output=True,
                             check=True).stdout.decode()
        names = [n for n in out.split('\0') if n]
    except (OSError, subprocess.CalledProcessError):
        skip = {'build', 'install', 'log', 'results', 'bags', 'node_modules', '__pycache__'}
        names = [str(p.relative_to(repo)) for p in repo.rglob('*')
                 if p.is_file() and not any(part.startswith('.') or part in skip
                                            for part in p.relative_to(repo).parts[:-1])]
    return [repo / n for n in names if (repo / n).is_file()]


def strip_fences(text: str) -> str:
    """``text`` with its fenced code blocks blanked (line numbers kept)."""
    out, fence = [], None
    for line in text.split('\n'):
        m = re.match(r'^ {0,3}(`{3,}|~{3,})', line)
        if fence is None and m:
            fence = m.group(1)
            out.append('')
            continue
        if fence is not None:
            if line.strip().startswith(fence[0] * len(fence)) and \
                    set(line.strip()) <= {fence[0]}:
                fence = None
            out.append('')
            continue
        out.append(line)
    return '\n'.join(out)


def strip_code(text: str) -> str:
    """``text`` with fenced code blocks, inline code spans and HTML comments blanked (line
    numbers kept)."""
    text = re.sub(r'<!--.*?-->', lambda m: '\n' * m.group(0).count('\n'), strip_fences(text),
                  flags=re.S)
    return re.sub(r'(`+)(.+?)\1', lambda m: ' ' * len(m.group(0)), text)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading's text."""
    text = re.sub(r'!?\[([^\]]*)\]\([^)]*\)', r'\1', heading)       # links: their text
    text = re.sub(r'<[^>]+>', '', text).strip().lower()              # inline HTML
    text = re.sub(r'[^\w\- ]', '', text)                             # punctuation, symbols
    return text.replace(' ', '-')


def anchors(path: Path) -> set[str]:
    """Every anchor GitHub gives the headings of the Markdown file ``path``."""
    seen: dict[str, int] = {}
    out = set()
    text = path.read_text(encoding='utf-8')
    out.update(HTML_ANCHOR.findall(text))
    for line in strip_fences(text).split('\n'):
        m = HEADING.match(line)
        if m is None:
            continue
        base = slug(m.group(2))
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f'{base}-{n}')
    return out


def numbered_sections(path: Path) -> set[int]:
    """The numbers of the headings ``n. Title`` of ``path``."""
    out = set()
    for line in strip_fences(path.read_text(encoding='utf-8')).split('\n'):
        m = HEADING.match(line)
        if m and (k := NUMBERED.match(m.group(2))):
            out.add(int(k.group(1)))
    return out


def check_target(repo: Path, source: Path, target: str) -> str | None:
    """What is wrong with the link ``target`` of ``source`` (None: it resolves)."""
    if re.match(r'^[a-zA-Z][\w+.-]*:', target) or target.startswith('//'):
        return None                                                  # a URL
    path, _, anchor = target.partition('#')
    dest = source if not path else (source.parent / path).resolve()
    if path and not dest.exists():
        return f'{target}: no such file'
    if path and not dest.resolve().is_relative_to(repo.resolve()):
        return f'{target}: outside the repository'
    if anchor and dest.is_file() and dest.suffix == '.md' and anchor not in anchors(dest):
        return f'{target}: no heading with that anchor in {dest.relative_to(repo.resolve())}'
    return None


def broken_links(repo: Path, files: list[Path]) -> list[str]:
    """``file:line: problem`` for every relative link of the Markdown ``files`` that does not
    resolve."""
    problems = []
    for f in files:
        if f.suffix != '.md':
            continue
        text = strip_code(f.read_text(encoding='utf-8'))
        for pattern in (LINK, REF_DEF):
            for m in pattern.finditer(text):
                problem = check_target(repo, f, m.group(1))
                if problem:
                    line = text.count('\n', 0, m.start()) + 1
                    problems.append(f'{f.relative_to(repo)}:{line}: {problem}')
    return problems


def broken_citations(repo: Path, files: list[Path]) -> list[str]:
    """``file:line: problem`` for every ``docs/...`` citation in ``files`` that does not
    resolve."""
    problems = []
    design = repo / 'docs' / 'design.md'
    sections = numbered_sections(design) if design.exists() else set()
    for f in files:
        if f.suffix not in TEXT_SUFFIXES and f.name not in ('Makefile',):
            continue
        try:
            text = f.read_text(encoding='utf-8')
        except (UnicodeDecodeError, OSError):
            continue
        for i, line in enumerate(text.split('\n'), 1):
            where = f'{f.relative_to(repo)}:{i}'
            for m in DOCS_CITE.finditer(line):
                doc = repo / 'docs' / m.group(1)
                if not doc.exists():
                    problems.append(f'{where}: docs/{m.group(1)}: no such file')
                elif m.group(2) and m.group(2)[1:] not in anchors(doc):
                    problems.append(f'{where}: docs/{m.group(1)}{m.group(2)}: no such heading')
            for m in SECTION_CITE.finditer(line):
                for n in re.findall(r'\d+', m.group(1)):
                    if int(n) not in sections:
                        problems.append(f'{where}: docs/design.md §{n}: no section {n}')
    return problems


def test_slugs_follow_github():
    assert slug('8. Facts verified on this machine') == '8-facts-verified-on-this-machine'
    assert slug("The real robot's bridge (`bench/bench_bridge.py`)") == \
        'the-real-robots-bridge-benchbench_bridgepy'
    assert slug('Results, `improved` preset (10 seeds × 1000 episodes; seeds 0–9)') == \
        'results-improved-preset-10-seeds--1000-episodes-seeds-09'
    assert slug('[Linked](x.md) heading') == 'linked-heading'


@pytest.fixture
def tree(tmp_path):
    (tmp_path / 'docs').mkdir()
    (tmp_path / 'docs' / 'design.md').write_text(
        '# D\n\n## 1. One\n\n## 2. Two\n\n## Two\n\n## The `code` part\n')
    (tmp_path / 'README.md').write_text(
        'See [design](docs/design.md#2-two), [again](docs/design.md#two), [top](#top) and\n'
        '[code](docs/design.md#the-code-part).\n\n'
        '# Top\n\n```\n[not a link](nowhere.md)\n```\n`[nor this](nowhere.md)`\n')
    (tmp_path / 'code.py').write_text('# docs/design.md §1 and 2; docs/design.md#1-one\n')
    return tmp_path


def test_a_good_tree_passes(tree):
    files = [tree / 'README.md', tree / 'docs' / 'design.md', tree / 'code.py']
    assert broken_links(tree, files) == []
    assert broken_citations(tree, files) == []


@pytest.mark.parametrize('link', ['docs/nothing.md', 'docs/design.md#3-three', '#nowhere',
                                  'docs/design.md#two-1-extra', '../outside.md'])
def test_a_broken_link_fails(tree, link):
    (tree / 'README.md').write_text(f'[x]({link})\n')
    assert len(broken_links(tree, [tree / 'README.md'])) == 1


@pytest.mark.parametrize('cite', ['docs/design.md §3', 'docs/design.md §1, 7',
                                  'docs/nothing.md', 'docs/design.md#no-such'])
def test_a_broken_citation_fails(tree, cite):
    (tree / 'code.py').write_text(f'# see {cite}\n')
    assert len(broken_citations(tree, [tree / 'code.py'])) == 1


def test_every_link_of_the_repository_resolves():
    files = tracked(REPO)
    assert any(f.name == 'README.md' for f in files)
    problems = broken_links(REPO, files)
    assert problems == [], '\n'.join(problems)


def test_every_cited_section_of_the_docs_exists():
    files = [f for f in tracked(REPO) if f.name != Path(__file__).name]
    assert (REPO / 'docs' / 'design.md').exists()
    problems = broken_citations(REPO, files)
    assert problems == [], '\n'.join(problems)
