"""The documentation runs: README.md and docs/*.md cannot rot.

- every ```python block runs: a page's blocks in order, in one namespace, in a
  fresh working directory (a block may opt out with a first line
  ``# doctest: skip: REASON``, for a long run or a data file that is absent);
- every ``slr-ray ...`` command in a ```bash / ```console / ```sh block is
  accepted by the command's own argument parser;
- every such block is marked, on the line above its fence, as run here
  (``<!-- docs test: runs -->``: on data it makes itself, each command in
  order in a fresh directory, exit status 0) or not (``<!-- docs test: skip:
  REASON -->``: your own data, hours of work);
- every relative link (and image) points at a file or folder of the
  repository, and its #anchor, if any, at a heading of the page;
- the README stays short, starts with the two quick-start commands and lists
  every subcommand.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from slr_ray.cli import build_parser, main

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^```([\w-]*)[^\n]*\n(.*?)^```[ \t]*$", re.M | re.S)
LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
SKIP = "# doctest: skip"
SHELL = {"bash", "console", "sh", "shell"}
#: the mark on the line above a shell block's fence: run by the tests, or not and why
SHELL_MARK = re.compile(r"^<!-- docs test: (runs|skip: (.{10,}?)) -->$")


def _rel(page: Path) -> str:
    return page.relative_to(ROOT).as_posix()


def code_blocks(page: Path, langs) -> list[tuple[int, str]]:
    """``(line number, code)`` of the fenced blocks of ``page`` in one of ``langs``."""
    text = page.read_text(encoding="utf-8")
    return [(text.count("\n", 0, m.start()) + 2, m.group(2)) for m in FENCE.finditer(text)
            if m.group(1).lower() in langs]


def prose(text: str) -> str:
    """The page without its fenced blocks and inline code (links in code are not links)."""
    return re.sub(r"`[^`\n]*`", "", FENCE.sub("", text))


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    heading = re.sub(r"`([^`]*)`", r"\1", heading.strip().lower())
    return "".join(c for c in heading if c.isalnum() or c in " -_").replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    return {slug(h) for h in re.findall(r"^#{1,6} (.+?)\s*#*$", text, flags=re.M)}


def commands(page: Path) -> list[tuple[int, list[str]]]:
    """Every ``slr-ray`` command of the page's shell blocks, as the arguments after ``slr-ray``."""
    found = []
    for line_no, code in code_blocks(page, SHELL):
        for i, line in enumerate(code.replace("\\\n", " ").split("\n")):
            line = line.strip().removeprefix("$ ")
            if "slr-ray" not in line or line.startswith("#"):
                continue
            tokens = shlex.split(line, comments=True)
            # commands chained with && or ; (the quick start's `... && slr-ray demo`)
            chain, part = [], []
            for t in tokens + ["&&"]:
                if t in ("&&", ";", "||"):
                    chain.append(part)
                    part = []
                else:
                    part.append(t)
            found += [(line_no + i, p[1:]) for p in chain if p and p[0] == "slr-ray"]
    return found


def shell_marks(page: Path) -> list[tuple[int, str, str | None]]:
    """``(line number, code, mark)`` of the page's shell blocks that hold an ``slr-ray`` command;
    mark is ``'runs'``, ``'skip: REASON'`` or None (the line above the fence is not a mark)."""
    text = page.read_text(encoding="utf-8")
    out = []
    for m in FENCE.finditer(text):
        if m.group(1).lower() not in SHELL or "slr-ray" not in m.group(2):
            continue
        above = text[:m.start()].rstrip("\n").rsplit("\n", 1)[-1].strip()
        mark = SHELL_MARK.match(above)
        out.append((text.count("\n", 0, m.start()) + 2, m.group(2), mark.group(1) if mark else None))
    return out


PY_PAGES = [p for p in PAGES if code_blocks(p, {"python"})]
RUN_PAGES = [p for p in PAGES if any(mark == "runs" for _, _, mark in shell_marks(p))]
CLI_PAGES = [p for p in PAGES if commands(p)]


@pytest.mark.parametrize("page", PY_PAGES, ids=_rel)
def test_python_blocks_run(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": f"docs:{_rel(page)}"}
    for line_no, code in code_blocks(page, {"python"}):
        first = code.lstrip().split("\n", 1)[0]
        if first.startswith(SKIP):
            continue
        try:
            exec(compile(code, f"{_rel(page)}:{line_no}", "exec"), namespace)
        except Exception as e:
            raise AssertionError(f"{_rel(page)}, the block at line {line_no} fails: {e!r}") from e


def test_skipped_blocks_are_few_and_say_why():
    skipped = [(p, n, code.lstrip().split("\n", 1)[0]) for p in PAGES
               for n, code in code_blocks(p, {"python"}) if code.lstrip().startswith(SKIP)]
    for page, n, first in skipped:
        assert len(first.removeprefix(SKIP).strip(" :")) >= 10, f"{_rel(page)}:{n}: a skip needs its reason"
    assert len(skipped) <= 3, [f"{_rel(p)}:{n}" for p, n, _ in skipped]


@pytest.mark.parametrize("page", CLI_PAGES, ids=_rel)
def test_shell_blocks_say_whether_they_run(page):
    unmarked = [n for n, _, mark in shell_marks(page) if mark is None]
    assert not unmarked, (f"{_rel(page)}: the shell blocks at lines {unmarked} need '<!-- docs test: runs -->' "
                          "or '<!-- docs test: skip: REASON -->' on the line above the fence")


@pytest.mark.parametrize("page", RUN_PAGES, ids=_rel)
def test_runnable_shell_blocks_run(page, tmp_path, monkeypatch, capsys):
    from slr_ray.cli import main

    monkeypatch.chdir(tmp_path)
    for line_no, code, mark in shell_marks(page):
        if mark != "runs":
            continue
        for i, line in enumerate(code.replace("\\\n", " ").split("\n")):
            tokens = shlex.split(line, comments=True)
            if not tokens:
                continue
            assert tokens[0] == "slr-ray", f"{_rel(page)}:{line_no + i}: a block that runs holds slr-ray commands only"
            rc = main(tokens[1:])
            err = capsys.readouterr().err.strip().splitlines()
            assert rc == 0, f"{_rel(page)}:{line_no + i}: `{line.strip()}` exits {rc}: {err[-1:] or ''}"


@pytest.mark.parametrize("page", CLI_PAGES, ids=_rel)
def test_documented_commands_parse(page):
    parser = build_parser()
    for line_no, argv in commands(page):
        try:
            parser.parse_args(argv)
        except SystemExit as e:
            raise AssertionError(f"{_rel(page)}:{line_no}: `slr-ray {shlex.join(argv)}` is refused "
                                 f"by the parser (exit {e.code})") from None


def test_command_parsing_is_checked():
    """The parser test can fail: an unknown flag is refused, a good line found."""
    with pytest.raises(SystemExit):
        build_parser().parse_args(["scan", "in.ply", "-o", "out.ply", "--no-such-flag"])
    assert any(argv[0] == "demo" for _, argv in commands(README))


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_relative_links_resolve(page):
    bad = []
    for target in LINK.findall(prose(page.read_text(encoding="utf-8"))):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if ROOT not in dest.parents and dest != ROOT:
            bad.append(f"{target}: outside the repository")
        elif not dest.exists():
            bad.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            bad.append(f"{target}: no such heading in {_rel(dest)}")
    assert not bad, f"{_rel(page)}: " + "; ".join(bad)


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_no_paths_outside_the_repository(page):
    """A user with a wheel has only the repository: no ../shared paths, and named scripts exist."""
    text = page.read_text(encoding="utf-8")
    assert "../shared" not in text and "/work/" not in text
    for script in re.findall(r"\b((?:benchmarks|tests)/[\w/]+\.py)\b", text):
        assert (ROOT / script).exists(), f"{_rel(page)} names {script}, which does not exist"


def _cli_flags(parser) -> set[str]:
    flags = set()
    for action in parser._actions:
        flags.update(action.option_strings)
        if isinstance(action.choices, dict):  # a subcommand's parsers
            for sub in action.choices.values():
                flags |= _cli_flags(sub)
    return flags


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_flags_named_in_the_text_exist(page):
    """A flag the prose names on its own (`--primary-origin`) is a flag of some subcommand."""
    named = {span.split()[0] for span in re.findall(r"`(--[a-z][^`]*)`", FENCE.sub("", page.read_text()))}
    assert not named - _cli_flags(build_parser()), f"{_rel(page)} names flags slr-ray does not have"


def test_every_docs_page_is_in_the_index():
    index = (ROOT / "docs" / "index.md").read_text(encoding="utf-8")
    linked = set(LINK.findall(prose(index)))
    missing = [p.name for p in PAGES[1:] if p.name != "index.md" and p.name not in linked]
    assert not missing


def test_readme_is_short_and_starts_with_the_quick_start():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 300
    first = code_blocks(README, SHELL)[0][1]
    setup = ("apt-get update && apt-get install -y libusb-1.0-0 python3-venv && python3 -m venv .venv "
             "&& . .venv/bin/activate && pip install -e")  # a virtual environment: Debian 12 refuses the system's
    lines = [l for l in first.splitlines() if l.strip() and not l.startswith("#")]
    assert lines == [f"{setup} . && slr-ray demo", f"{setup} '.[test]' && python -m pytest -q"]
    assert text.index("```") == text.index("```bash\n# 1. set up")  # the first code of the page


def test_readme_lists_every_command():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "cmd")
    table = {m for m in re.findall(r"^\| `slr-ray (\w+)", README.read_text(encoding="utf-8"), flags=re.M)}
    assert table == set(sub.choices)
