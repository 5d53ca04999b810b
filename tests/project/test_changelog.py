"""CHANGELOG.md in Keep a Changelog's form (https://keepachangelog.com/en/1.1.0/): the top heading, then
``## [Unreleased]``, then released versions ``## [X.Y.Z] - YYYY-MM-DD``, newest first, each with its link
reference at the bottom; every entry a bullet under one of the form's subsections."""

from __future__ import annotations

import re
from pathlib import Path

from tests.project.test_static_gates import TICKET

ROOT = Path(__file__).resolve().parents[2]
CHANGELOG = ROOT / "CHANGELOG.md"

#: Keep a Changelog's subsections, in the order a version lists them.
SUBSECTIONS = ("Added", "Changed", "Deprecated", "Removed", "Fixed", "Security")
_ALLOWED = ", ".join(f"### {name}" for name in SUBSECTIONS)
_RELEASE = re.compile(r"## \[(\d+)\.(\d+)\.(\d+)\] - (\d{4})-(\d\d)-(\d\d)")
_LINK_DEFINITION = re.compile(r"\[([^\]]+)\]: \S+")


def _version(number: int, line: str, first: bool) -> tuple[str, list[str]]:
    """A ``## `` heading's version name and what is wrong with it."""
    found = []
    if line == "## [Unreleased]":
        name = "Unreleased"
        if not first:
            found.append(f"line {number}: `## [Unreleased]` is the first version heading")
    elif _RELEASE.fullmatch(line):
        name = line[4:line.index("]")]
    else:
        name = ""
        found.append(f"line {number}: a version heading is `## [Unreleased]` or `## [X.Y.Z] - YYYY-MM-DD`, "
                     f"not {line!r}")
    if first and name != "Unreleased":
        found.append(f"line {number}: the first version heading is `## [Unreleased]`")
    return name, found


def _subsection(number: int, line: str, seen: list[str]) -> list[str]:
    """What is wrong with a ``### `` heading, after the version's subsections ``seen``."""
    name = line[4:]
    if name not in SUBSECTIONS:
        return [f"line {number}: {line!r} is not one of Keep a Changelog's subsections: {_ALLOWED}"]
    if name in seen:
        return [f"line {number}: a second {line!r} in the same version"]
    if any(SUBSECTIONS.index(name) < SUBSECTIONS.index(s) for s in seen if s in SUBSECTIONS):
        return [f"line {number}: the subsections go in the order {_ALLOWED}"]
    return []


def _versions_complete(lines: list[str], versions: list[tuple[int, str]], links: dict[str, int],
                       last_entry: int) -> list[str]:
    """Every version has entries and (a release) its link reference, below the entries; releases newest first."""
    found = []
    ends = [number for number, _ in versions[1:]] + [len(lines) + 1]
    for (number, name), end in zip(versions, ends):
        if not any(line.startswith("- ") for line in lines[number:end - 1]):
            found.append(f"line {number}: version {name or lines[number - 1]} has no entries")
        if _RELEASE.fullmatch(lines[number - 1]) and name not in links:
            found.append(f"line {number}: version {name} has no link reference `[{name}]: URL` at the bottom")
    headings = [number for number, line in enumerate(lines, 1) if line.startswith("#")] + [len(lines) + 1]
    found += [f"line {number}: {lines[number - 1]!r} has no entries: leave it out" for number, end in
              zip(headings, headings[1:]) if lines[number - 1].startswith("### ")
              and not any(line.startswith("- ") for line in lines[number:end - 1])]
    found += [f"line {number}: the link reference [{name}] comes after the last entry, at the bottom"
              for name, number in links.items() if number < last_entry]
    released = [tuple(int(x) for x in match.groups()) for match in
                (_RELEASE.fullmatch(lines[number - 1]) for number, _ in versions) if match]
    if released != sorted(released, reverse=True):
        found.append("the released versions go newest first, by number and by date")
    return found


def problems(text: str) -> list[str]:
    """What in ``text`` (a changelog) breaks the form, one line per finding, ``line N: ...``."""
    lines = text.splitlines()
    found = []
    if not lines or lines[0] != "# Changelog":
        found.append("line 1: the first line is `# Changelog`")
    header = "\n".join(lines[:next((i for i, line in enumerate(lines) if line.startswith("## ")), len(lines))])
    if "keepachangelog.com" not in header or "semver.org" not in header:
        found.append("the header says that the file follows Keep a Changelog and Semantic Versioning (with links)")
    versions: list[tuple[int, str]] = []  # (line number, name) of each ``## [name]`` heading
    seen: list[str] = []  # the current version's subsections so far
    links: dict[str, int] = {}  # the line of each link reference definition, by name
    last_entry = 0
    for number, line in enumerate(lines, 1):
        link = _LINK_DEFINITION.fullmatch(line)
        if line.startswith("## "):
            name, wrong = _version(number, line, first=not versions)
            found += wrong
            versions.append((number, name))
            seen = []
        elif line.startswith("### "):
            found += _subsection(number, line, seen) if versions else [
                f"line {number}: a subsection before the first version heading"]
            seen.append(line[4:])
        elif line.startswith("#") and number > 1:
            found.append(f"line {number}: only `#` (the title), `##` (versions) and `###` (subsections) headings")
        elif link:
            links[link.group(1)] = number
        elif line.startswith("- ") and versions:
            last_entry = number
            if not seen:
                found.append(f"line {number}: an entry straight under {lines[versions[-1][0] - 1]!r}: put it at "
                             f"the top of its subsection, one of {_ALLOWED}")
        elif versions and line.strip() and not (line.startswith("  ") and last_entry):
            found.append(f"line {number}: under a version, everything is a `- ` bullet (continued indented) "
                         f"in a subsection")
    if not versions:
        found.append("no `## [Unreleased]` heading")
    return found + _versions_complete(lines, versions, links, last_entry)


def test_the_changelog_keeps_the_form():
    found = problems(CHANGELOG.read_text())
    assert found == [], "CHANGELOG.md:\n" + "\n".join(found)


def test_the_changelog_names_no_internal_ticket():
    text = CHANGELOG.read_text()
    found = [f"line {text.count(chr(10), 0, m.start()) + 1}: {m.group()}" for m in TICKET.finditer(text)]
    assert found == [], "say what the finding, measurement or field is instead"


GOOD = """# Changelog

Follows [Keep a Changelog](https://keepachangelog.com/en/1.1.0/) and [Semantic
Versioning](https://semver.org/spec/v2.0.0.html).

## [Unreleased]

### Added

- a feature,
  on two lines.

### Fixed

- a fix.

## [0.2.0] - 2026-11-02

### Removed

- an option.

## [0.1.0] - 2026-01-05

### Added

- the first release.

[Unreleased]: https://example.org/compare/v0.2.0...HEAD
[0.2.0]: https://example.org/compare/v0.1.0...v0.2.0
[0.1.0]: https://example.org/releases/tag/v0.1.0
"""


def test_a_misplaced_entry_or_a_wrong_heading_is_found():
    assert problems(GOOD) == []
    # an entry added at the top of Unreleased, as before there were subsections
    misplaced = problems(GOOD.replace("## [Unreleased]\n", "## [Unreleased]\n\n- a new entry.\n"))
    assert len(misplaced) == 1 and "line 8: an entry straight under '## [Unreleased]'" in misplaced[0]
    assert "### Added, ### Changed, ### Deprecated, ### Removed, ### Fixed, ### Security" in misplaced[0]
    assert problems(GOOD.replace("## [Unreleased]", "## Unreleased")) == [
        "line 6: a version heading is `## [Unreleased]` or `## [X.Y.Z] - YYYY-MM-DD`, not '## Unreleased'",
        "line 6: the first version heading is `## [Unreleased]`"]
    assert problems(GOOD.replace("### Fixed", "### Improved"))[0].startswith("line 13: '### Improved' is not one")
    assert problems(GOOD.replace("### Fixed", "### Added")) == ["line 13: a second '### Added' in the same version"]
    assert problems(GOOD.replace("[0.1.0]: https://example.org/releases/tag/v0.1.0\n", "")) == [
        "line 23: version 0.1.0 has no link reference `[0.1.0]: URL` at the bottom"]
    assert problems(GOOD.replace("- 2026-11-02", "- 2 November")) != []
    assert problems(GOOD.replace("### Fixed\n\n- a fix.\n", "### Fixed\n")) == [
        "line 13: '### Fixed' has no entries: leave it out"]
    swapped = GOOD.replace("0.2.0", "0.0.9")
    assert problems(swapped) == ["the released versions go newest first, by number and by date"]
