"""The manual stays true to the code: every command is one click from the README, every option is on its page,
every relative link lands on a file (and a heading), and the README stays a front page.

The commands are read from the typer apps themselves (`typer.main.get_command(app).commands`), so a new command
is covered as soon as it is registered.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest
import typer

from dome_calib.cli import app as dome_calib_app
from timecode.cli import app as timecode_app

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
MAX_README_LINES = 260

PROGRAMS = {"dome-calib": dome_calib_app, "timecode": timecode_app}


def _commands() -> list[tuple[str, str, object]]:
    """(program, command name, click command) for every registered command, sub-commands as "group sub"."""
    found = []

    def walk(prog: str, prefix: str, group) -> None:
        for name, cmd in sorted(group.commands.items()):
            full = f"{prefix} {name}".strip()
            if getattr(cmd, "hidden", False):
                continue
            if hasattr(cmd, "commands"):  # a typer sub-app: its options belong on the group's page
                walk(prog, full, cmd)
            found.append((prog, full, cmd))

    for prog, app in PROGRAMS.items():
        walk(prog, "", typer.main.get_command(app))
    return found


def _option_names(cmd) -> list[str]:
    """Every name of every visible option of a command (long and short), sub-commands' included."""
    names = []
    for param in getattr(cmd, "params", []):
        if param.param_type_name == "option" and not getattr(param, "hidden", False):
            names += [n for n in [*param.opts, *param.secondary_opts] if n != "--help"]
    for sub in getattr(cmd, "commands", {}).values():
        names += _option_names(sub)
    return sorted(set(names))


COMMANDS = _commands()
ROW = re.compile(r"^\|\s*`(dome-calib|timecode) ([a-z][a-z0-9-]*(?: [a-z][a-z0-9-]*)*)(?=[ `])")
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)
INLINE_CODE = re.compile(r"`[^`\n]*`")


def _without_code(text: str) -> str:
    """Markdown text with fenced blocks and inline code spans blanked (a link's text may be code: kept empty)."""
    return INLINE_CODE.sub("", FENCE.sub("", text))


def _table_rows() -> dict[tuple[str, str], str]:
    """(program, command) -> the README table row that names it first."""
    rows = {}
    for line in README.read_text(encoding="utf-8").splitlines():
        match = ROW.match(line)
        if match:
            rows.setdefault((match.group(1), match.group(2)), line)
    return rows


def _doc_links(row: str) -> list[Path]:
    """The docs pages a README table row links to (anchors dropped)."""
    pages = []
    for target in LINK.findall(_without_code(row)):
        path = target.split("#", 1)[0]
        if path.startswith("docs/") and path.endswith(".md"):
            pages.append(ROOT / path)
    return pages


def _markdown_files() -> list[Path]:
    return [README, *sorted(DOCS.glob("*.md"))]


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: links reduced to their text, lower case, punctuation dropped, spaces -> '-'."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    anchors: set[str] = set()
    counts: dict[str, int] = {}
    for line in FENCE.sub("", path.read_text(encoding="utf-8")).splitlines():
        match = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if match:
            slug = _slug(match.group(1))
            n = counts.get(slug, 0)
            anchors.add(slug if n == 0 else f"{slug}-{n}")
            counts[slug] = n + 1
    return anchors


def _relative_links() -> list[tuple[Path, str]]:
    links = []
    for path in _markdown_files():
        for target in LINK.findall(_without_code(path.read_text(encoding="utf-8"))):
            if not re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto: are not ours to check
                links.append((path, target))
    return links


def test_commands_found() -> None:
    """The apps are read: the commands every layout of the CLI has are there (guards the walk itself)."""
    names = {(prog, name) for prog, name, _ in COMMANDS}
    assert {("dome-calib", "calibrate"), ("dome-calib", "session"), ("timecode", "decode"),
            ("timecode", "sync")} <= names
    assert "--only-changed" in _option_names(dict(((p, n), c) for p, n, c in COMMANDS)[("dome-calib", "calibrate")])


@pytest.mark.parametrize(("prog", "name", "cmd"), COMMANDS, ids=[f"{p} {n}" for p, n, _ in COMMANDS])
def test_command_in_readme_table_with_its_page(prog: str, name: str, cmd) -> None:
    """Every registered command has a README table row whose link leads to an existing page naming every option."""
    row = _table_rows().get((prog, name))
    assert row is not None, f"README.md: no table row starting with `{prog} {name}`"
    pages = _doc_links(row)
    assert pages, f"README.md: the row of `{prog} {name}` links to no docs/*.md page"
    missing_pages = [str(p.relative_to(ROOT)) for p in pages if not p.is_file()]
    assert not missing_pages, f"README.md: the row of `{prog} {name}` links to missing {missing_pages}"
    text = "\n".join(p.read_text(encoding="utf-8") for p in pages)
    absent = [o for o in _option_names(cmd) if not re.search(rf"(?<![\w-]){re.escape(o)}(?![\w-])", text)]
    assert not absent, f"{[str(p.relative_to(ROOT)) for p in pages]}: options of `{prog} {name}` not documented: {absent}"


def test_readme_rows_name_registered_commands() -> None:
    """No README row describes a command that does not exist (a renamed or removed one)."""
    registered = {(prog, name) for prog, name, _ in COMMANDS}
    stale = sorted(f"{p} {n}" for p, n in _table_rows() if (p, n) not in registered)
    assert not stale, f"README.md: table rows for commands that are not registered: {stale}"


def test_readme_is_a_front_page() -> None:
    n_lines = len(README.read_text(encoding="utf-8").splitlines())
    assert n_lines <= MAX_README_LINES, f"README.md has {n_lines} lines; at most {MAX_README_LINES} (the depth goes to docs/)"


def test_relative_links_resolve() -> None:
    """Every relative link (and image) in README.md and docs/*.md names an existing file or folder."""
    broken = []
    for path, target in _relative_links():
        file_part = target.split("#", 1)[0]
        if file_part and not (path.parent / file_part).exists():
            broken.append(f"{path.relative_to(ROOT)}: {target}")
    assert not broken, "links to missing files:\n" + "\n".join(broken)


def test_anchors_resolve() -> None:
    """Every `page.md#anchor` (or `#anchor`) link names a heading of an existing markdown page."""
    broken = []
    for path, target in _relative_links():
        if "#" not in target:
            continue
        file_part, anchor = target.split("#", 1)
        page = (path.parent / file_part) if file_part else path
        if page.suffix == ".md" and page.is_file() and anchor not in _anchors(page):
            broken.append(f"{path.relative_to(ROOT)}: {target}")
    assert not broken, "links to missing headings:\n" + "\n".join(broken)


def test_help_cites_only_existing_readme_sections() -> None:
    """A --help that sends the reader to a README section ('see README, 'X'') names one that exists."""
    headings = {re.sub(r"^#+\s*", "", line).strip().strip("`").lower()
                for line in README.read_text(encoding="utf-8").splitlines() if line.startswith("#")}
    cited = []
    for prog, name, cmd in COMMANDS:
        texts = [cmd.help or ""] + [getattr(p, "help", None) or "" for p in cmd.params]
        for text in texts:
            for section in re.findall(r"README,?\s*'([^']+)'", text):
                if section.lower() not in headings:
                    cited.append(f"{prog} {name}: README '{section}'")
    assert not cited, "--help cites README sections that do not exist (point at the docs page):\n" + "\n".join(cited)


def test_slug_matches_github() -> None:
    """The anchor rule used above, on headings of the kinds the manual has."""
    assert _slug("On the dome's own nodes (`--scheduler`)") == "on-the-domes-own-nodes---scheduler"
    assert _slug("Kinect `M_color`") == "kinect-m_color"
    assert _slug("`make demo`: the tiny dome") == "make-demo-the-tiny-dome"
