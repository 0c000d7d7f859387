"""The documentation as a newcomer meets it: a short README, the details in doc/, no history.

README.md is the front door (at most README_MAX_LINES lines, with a Limitations section); the
pages of doc/ hold the rest. Neither refers to anything outside the repository, names a
commit, or links to a file or heading that does not exist, and both source papers are cited
by their titles. The code map is one, in doc/design.md, and names every module.
"""
import pathlib
import re

import pytest

REPO = pathlib.Path(__file__).resolve().parent.parent
README = REPO / 'README.md'
DOC = REPO / 'doc'
README_MAX_LINES = 450
MIN_DOC_PAGES = 3
PAPER_TITLES = ('Engine Algorithms', 'Discrete Collision Algorithms')
# A commit hash: 7-40 hex digits with at least one letter and one digit, not part of a longer
# word, number or path (so "1e-6", "float64" and "d153dac.py" style names are judged whole).
COMMIT_HASH = re.compile(r'(?<![\w./-])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}'
                         r'(?![\w/-])')
# Outside the repository: the design guide and the papers kept beside it, or a path that climbs
# out of it (a page of doc/ may link ../README.md; links are checked to stay inside below).
OUTSIDE = re.compile(r'\.\./\.\./|\.\./(?!README\.md)|DESIGN\.md|DESIGN §|\bshared/|\bseeds/')
LINK = re.compile(r'\]\(([^)\s]+)\)')


def pages():
    """Return README.md and every markdown page of doc/."""
    return [README] + sorted(DOC.glob('*.md'))


def anchor(heading):
    """Return GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r'[^\w\- ]', '', heading.strip().lower())
    return text.replace(' ', '-')


def anchors(page):
    """Return the anchors of a page's headings (outside code blocks), numbered as GitHub does."""
    found, seen = set(), {}
    text = re.sub(r'^```.*?^```', '', page.read_text(), flags=re.MULTILINE | re.DOTALL)
    for heading in re.findall(r'^#+ (.*)$', text, re.MULTILINE):
        name = anchor(heading)
        count = seen.get(name, 0)
        seen[name] = count + 1
        found.add(name if count == 0 else '%s-%d' % (name, count))
    return found


def prose(page):
    """Return a page's text without its code blocks (links inside code are not links)."""
    return re.sub(r'^```.*?^```', '', page.read_text(), flags=re.MULTILINE | re.DOTALL)


def test_readme_is_short_and_says_what_it_cannot_do():
    lines = README.read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, 'README.md has %d lines' % len(lines)
    assert re.search(r'^## Limitations$', README.read_text(), re.MULTILINE)


def test_one_code_map_names_every_module():
    design = (DOC / 'design.md').read_text()
    start = design.index('\n## Code map\n')
    end = design.find('\n## ', start + 1)
    code_map = design[start:end if end > 0 else len(design)]
    package = REPO / 'collision_node'
    modules = [path.relative_to(package).as_posix() for path in sorted(package.glob('*/**/*.py'))]
    assert [name for name in modules if '`%s`' % name not in code_map] == []
    readme = README.read_text()
    assert '(doc/design.md#code-map)' in readme
    assert 'pipeline/obb.py' not in readme, 'the README links to the code map, not a copy of it'


def test_doc_has_pages_each_saying_what_it_answers():
    found = sorted(DOC.glob('*.md'))
    assert len(found) >= MIN_DOC_PAGES, found
    for page in found:
        first = page.read_text().splitlines()[:4]
        assert first[0].startswith('# ') and any(line.strip() for line in first[1:]), page


@pytest.mark.parametrize('page', pages(), ids=lambda page: page.name)
def test_no_commit_hash(page):
    assert COMMIT_HASH.findall(page.read_text()) == []


@pytest.mark.parametrize('page', pages(), ids=lambda page: page.name)
def test_no_reference_outside_the_repository(page):
    assert OUTSIDE.findall(page.read_text()) == []
    if page == README:
        assert '../' not in page.read_text()


@pytest.mark.parametrize('page', pages(), ids=lambda page: page.name)
def test_every_relative_link_resolves(page):
    broken = []
    for target in LINK.findall(prose(page)):
        if re.match(r'[a-z]+:', target):  # https:, mailto:
            continue
        path, _, fragment = target.partition('#')
        linked = (page.parent / path).resolve() if path else page
        if not linked.exists() or REPO not in linked.parents and linked != REPO:
            broken.append(target)
        elif fragment and linked.suffix == '.md' and fragment not in anchors(linked):
            broken.append(target)
    assert broken == []


def test_both_papers_are_cited_by_title():
    text = '\n'.join(page.read_text() for page in pages())
    for title in PAPER_TITLES:
        assert '"%s"' % title in text, title


def test_the_checks_would_catch_what_they_look_for():
    assert COMMIT_HASH.findall('at b0ecb1e, then 431a7bd') == ['b0ecb1e', '431a7bd']
    assert COMMIT_HASH.findall('float64 1e-6 deadbeefcafe 2026-11-25 3.84 ms 100000') == []
    assert OUTSIDE.findall('see ../shared/seeds/000 and DESIGN.md') != []
    assert OUTSIDE.findall('[the README](../README.md#topics)') == []
    assert anchor('Static colliders that move (`collision_bench --only static_moves`)') == \
        'static-colliders-that-move-collision_bench---only-static_moves'
