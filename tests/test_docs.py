"""The documentation stays usable: a short README, links that resolve, citations
inside the repository, and a quick start that is the Makefile's."""

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"

#: Pages other branches of this round write. A link to one is skipped only while
#: it is absent; ``test_pending_pages_are_still_pending`` fails as soon as one
#: lands, so that it leaves this set and its links are checked like every other.
PENDING: set[str] = set()

#: The background notes the project was built from, outside the repository.
OUTSIDE_NOTES = r"\b(?:SPEC|DYNAMIXEL|SIM|TRACKING|RETIME|ONLINE|PERF|GIMBALS|STYLE)\.md\b"
OUTSIDE = re.compile(rf"\.\./shared|shared/\w+\.md|{OUTSIDE_NOTES}|\bSPEC (?:\d|section)")

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```[^\n]*$", re.S | re.M)
CODE_SPAN = re.compile(r"`[^`\n]*`")
HEADING = re.compile(r"^(#{1,6}) +(.+?) *#*$", re.M)


def _markdown_files() -> list[Path]:
    return [README, *sorted(DOCS.glob("*.md"))]


def _prose(text: str) -> str:
    """The text without fenced code blocks and code spans (links there are not links)."""
    return CODE_SPAN.sub("", FENCE.sub("", text))


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*]|\[([^\]]*)\]\([^)]*\)", r"\1", heading).lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for _, title in HEADING.findall(FENCE.sub("", path.read_text())):
        slug = _slug(title)
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def _tracked_files() -> list[Path]:
    """Every file git tracks (or would track: new files not ignored); outside a git
    checkout, every file but the virtualenv's and the caches'."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "--cached", "--others", "--exclude-standard"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        skip = {".git", ".venv", "out", "build", "__pycache__", ".pytest_cache", ".ruff_cache"}
        return [
            p
            for p in ROOT.rglob("*")
            if p.is_file()
            and not any(
                part in skip or part.startswith(".hypothesis") or part.endswith(".egg-info")
                for part in p.relative_to(ROOT).parts
            )
        ]
    return [ROOT / name for name in out if (ROOT / name).is_file()]


def _text(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        return None  # a figure or other binary file


def test_readme_is_short():
    lines = README.read_text().count("\n")
    assert lines < 400, f"README.md has {lines} lines; move detail into docs/"


@pytest.mark.parametrize("page", _markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    broken = []
    for target in LINK.findall(_prose(page.read_text())):
        if re.match(r"[a-z]+:", target):  # https:, mailto:
            continue
        name, _, anchor = target.partition("#")
        path = (page.parent / name).resolve() if name else page
        if not path.exists():
            if path.parent == DOCS and path.name in PENDING:
                continue
            broken.append(f"{target}: no such file")
        elif anchor and path.suffix == ".md" and anchor not in _anchors(path):
            broken.append(f"{target}: no heading #{anchor} in {path.name}")
    assert broken == []


def test_pending_pages_are_still_pending():
    landed = sorted(name for name in PENDING if (DOCS / name).exists())
    assert landed == [], f"remove {landed} from PENDING in tests/test_docs.py"


def test_nothing_cites_notes_outside_the_repository():
    offenders = []
    for path in _tracked_files():
        if path == Path(__file__).resolve():
            continue
        text = _text(path)
        if text is None:
            continue
        for number, line in enumerate(text.splitlines(), 1):
            if OUTSIDE.search(line):
                offenders.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert offenders == [], "cite docs/algorithm.md (or another docs/ page) instead"


def test_citations_of_docs_point_at_existing_pages_and_sections():
    sections = {
        m.group(1)
        for m in re.finditer(
            r"^#{2,4} (\d+(?:\.\d+)?[a-z]?)[. ]", (DOCS / "algorithm.md").read_text(), re.M
        )
    }
    assert {"1", "2a", "2b", "2c", "3", "4", "6", "8", "8.2", "8.5"} <= sections
    broken = []
    for path in _tracked_files():
        if path.suffix not in {".py", ".toml", ".md", ".cfg"} and path.name != "Makefile":
            continue
        text = _text(path) or ""
        for page in re.findall(r"\bdocs/([\w-]+\.md)", text):
            if not (DOCS / page).exists() and page not in PENDING:
                broken.append(f"{path.relative_to(ROOT)}: docs/{page}")
        for section in re.findall(r"algorithm\.md §(\d+(?:\.\d+)?[a-z]?)", text):
            if section not in sections:
                broken.append(f"{path.relative_to(ROOT)}: algorithm.md §{section}")
    assert broken == []


def test_quick_start_is_the_makefiles_demo_and_test_which_install_what_they_need():
    text = README.read_text()
    quick = text.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"^```[^\n]*\n(.*?)^```", quick, re.S | re.M)
    assert block is not None, "the quick start has no command block"
    assert block.group(1).split("\n")[:-1] == ["make demo", "make test"]
    makefile = (ROOT / "Makefile").read_text()
    stamp = re.search(r"^\$\(STAMP\):.*\n((?:\t.*\n)+)", makefile, re.M)
    assert stamp is not None and "pip install" in stamp.group(1)
    assert re.search(r"-e '\.\[dev\]'", stamp.group(1)), "make test must install the dev extra"
    for target in ("demo", "test"):
        rule = re.search(rf"^{target}:(.*)$", makefile, re.M)
        assert rule is not None, f"the Makefile has no {target} target"
        assert "$(STAMP)" in rule.group(1).split(), f"make {target} does not install first"


def _blocks(language: str) -> list[str]:
    return re.findall(rf"^```{language}\n(.*?)^```", README.read_text(), re.S | re.M)


def test_the_readmes_keyframe_file_is_a_valid_file_for_the_servos(tmp_path):
    from trajgen import load_keyframe_file
    from trajgen.drivers.config import bus_config_from_tables

    (block,) = _blocks("toml")
    path = tmp_path / "keys.toml"
    path.write_text(block)
    keys = load_keyframe_file(path)
    assert keys.times.tolist() == [0.0, 2.0, 4.0]
    bus = bus_config_from_tables(keys.tables, path)
    assert (bus.port, bus.baud) == ("/dev/ttyUSB0", 1_000_000)


def test_the_readmes_library_example_runs_and_passes_its_torque_check():
    (block,) = _blocks("python")
    namespace: dict = {}
    exec(compile(block, "README.md", "exec"), namespace)  # raises if the check fails
    assert namespace["report"].ok
