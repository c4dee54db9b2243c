"""The documentation as tests: the MkDocs site builds with --strict, every `pih` command line shown in README.md and
in the code blocks of docs/ parses with the CLI's own argparse parser, and the README stays a front door (at most
MAX_README_LINES lines, its links resolve, no history: issue numbers, commit hashes and session-relative dates belong
in CHANGELOG.md); and the Python sources' docstrings and comments keep the what and why, not the history (the same
`history_markers`, over every module of the packages)."""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
MAX_README_LINES = 250

SHELL_FENCES = {"", "bash", "sh", "shell", "console"}
"""Info strings of the fenced code blocks whose lines are shell commands."""
SEPARATORS = {"&&", "||", ";", "|", "&"}
"""Shell operators that end one command and start the next."""
REDIRECTIONS = {">", ">>", "<", ">&", "2>"}
"""Redirections: the operator and the word after it are no arguments of the command."""


def doc_files() -> list[Path]:
    """README.md and every Markdown page of the documentation (the CHANGELOG is history, never checked here)."""
    return [README, *sorted(DOCS.rglob("*.md"))]


# --- every `pih ...` line of the docs parses ---------------------------------------------------------------------


@dataclass(frozen=True)
class ShownCommand:
    """A `pih` command line shown in a document: where, and its words after `pih`."""

    path: Path
    line: int
    words: tuple[str, ...]
    error: str = ""
    """Why the line could not be read as shell (an unclosed quote), if it could not."""

    def where(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}: pih {shlex.join(self.words)}"


def shell_blocks(text: str) -> list[tuple[int, list[str]]]:
    """The fenced shell code blocks of a Markdown text: (line number of the block's first line, its lines)."""
    blocks: list[tuple[int, list[str]]] = []
    fence, shell, lines, start = "", False, [], 0
    for number, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if not fence:
            match = re.match(r"^(```+|~~~+)\s*([\w+-]*)", stripped)
            if match:
                fence, shell, lines, start = match.group(1), match.group(2).lower() in SHELL_FENCES, [], number + 1
        elif stripped.startswith(fence) and not stripped.strip(fence[0]):
            if shell:
                blocks.append((start, lines))
            fence = ""
        else:
            lines.append(line)
    return blocks


def commands_in(path: Path, text: str | None = None) -> list[ShownCommand]:
    """Every `pih` command in the fenced shell blocks of ``path``: continuation lines joined, comments dropped,
    variables assigned earlier in the same block (NAME="...") expanded, each command of a line (after &&, ;, |)
    taken alone, redirections left out. `pih` may be written as a path (.venv/bin/pih)."""
    found = []
    for start, lines in shell_blocks(path.read_text() if text is None else text):
        variables: dict[str, str] = {}
        logical: list[tuple[int, str]] = []
        pending, first = "", 0
        for offset, line in enumerate(lines):
            if not pending:
                first = start + offset
            if line.rstrip().endswith("\\"):
                pending += line.rstrip()[:-1] + " "
                continue
            logical.append((first, pending + line))
            pending = ""
        if pending:
            logical.append((first, pending))
        for number, line in logical:
            assignment = re.match(r"^\s*([A-Za-z_]\w*)=(.*)$", line)
            if assignment:
                variables[assignment.group(1)] = " ".join(shlex.split(assignment.group(2), comments=True))
                continue
            for name, value in variables.items():
                line = re.sub(rf"\$(?:{{{name}}}|{name}\b)", lambda _m, v=value: v, line)
            lexer = shlex.shlex(line, posix=True, punctuation_chars=";&|<>")
            lexer.whitespace_split = True
            lexer.commenters = "#"
            try:
                tokens = list(lexer)
            except ValueError as err:  # not shell (a diagram in a plain block), or a broken command line
                if re.search(r"(?:^|[\s/])pih\b", line):
                    found.append(ShownCommand(path, number, (line.strip(),), f"not a shell line: {err}"))
                continue
            segments: list[list[str]] = [[]]
            skip = False
            for token in tokens:
                if token in SEPARATORS:
                    segments.append([])
                elif token in REDIRECTIONS:
                    skip = True
                elif skip:
                    skip = False
                else:
                    segments[-1].append(token)
            for words in segments:
                if words and (words[0] == "pih" or words[0].endswith("/pih")):
                    found.append(ShownCommand(path, number, tuple(words[1:])))
    return found


def parse_failure(words: Iterable[str]) -> str | None:
    """Why `pih WORDS` does not parse with the CLI's own parser (scripts.cli.build_parser), or None when it does.
    Nothing runs: only the parser is built (it imports the one subcommand's module) and asked."""
    from scripts.cli import SUBCOMMANDS, UsageError, build_parser, chosen_command

    words = list(words)
    command = chosen_command(words)
    if "-h" in words or "--help" in words:
        return None if not command or command in SUBCOMMANDS else f"{command!r} is no pih command"
    try:
        build_parser(command).parse_args(words)
    except UsageError as err:
        return str(err)
    except SystemExit as err:  # argparse's own exit, should a parser not be the CLI's
        return f"the parser exited with status {err.code}"
    return None


def test_the_extraction_finds_commands_through_shell_syntax(tmp_path):
    text = "\n".join([
        "Some prose: pih not-in-a-block --x",
        "```bash",
        'M="--seed 3 --episodes 2"   # a variable',
        "pih demos --num 7 --seed 0 --out d.npz && pih train --demos d.npz \\",
        "    --out m/                # continued",
        "bash setup.sh && .venv/bin/pih run",
        "pih task show --task contact > my_task.toml",
        "pih evaluate --model m $M --json e.json",
        "```",
        "```python",
        "pih = 1  # not shell",
        "```",
    ])
    found = [(c.line, c.words) for c in commands_in(tmp_path / "x.md", text)]
    assert found == [
        (4, ("demos", "--num", "7", "--seed", "0", "--out", "d.npz")),
        (4, ("train", "--demos", "d.npz", "--out", "m/")),
        (6, ("run",)),
        (7, ("task", "show", "--task", "contact")),
        (8, ("evaluate", "--model", "m", "--seed", "3", "--episodes", "2", "--json", "e.json")),
    ]


@pytest.mark.parametrize("words", [
    ("evaluate", "--model", "m/", "--no-such-option"),           # an unknown option
    ("train", "--demos", "demos.npz"),                             # a required option missing (--out)
    ("evaluate", "--model", "m/", "--seed", "S"),                  # a placeholder where a number goes
    ("export", "--demos", "d.npz", "--format", "lerobot|robomimic", "--out", "ds/"),  # a choice that is no choice
    ("teleport",),                                                 # no such command
])
def test_the_parse_check_refuses_what_pih_refuses(words):
    assert parse_failure(words) is not None


def test_the_parse_check_takes_what_pih_takes():
    assert parse_failure(("evaluate", "--model", "A/sk/...", "--seed", "1005", "--stiffness", "constant:500")) is None
    assert parse_failure(("compare", "--help")) is None


def test_every_pih_command_shown_in_the_docs_parses():
    shown = [command for path in doc_files() for command in commands_in(path)]
    assert len([c for c in shown if c.path == README]) >= 15, "the README's commands were not found"
    failures = [f"{command.where()}\n    {reason}" for command in shown
                if (reason := command.error or parse_failure(command.words)) is not None]
    assert not failures, "pih command lines in the docs that pih does not parse:\n" + "\n".join(failures)


# --- the site builds --------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_the_site_builds_with_strict(tmp_path):
    missing = [name for name in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python")
               if importlib.util.find_spec(name) is None]
    if missing:
        pytest.skip(f"the docs tools are not installed ({', '.join(missing)}): pip install -e '.[docs]'")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(ROOT / "mkdocs.yml"),
         "--site-dir", str(tmp_path / "site")],
        cwd=ROOT, capture_output=True, text=True, timeout=600, check=False,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert result.returncode == 0, f"mkdocs build --strict failed:\n{result.stdout[-3000:]}\n{result.stderr[-6000:]}"
    assert (tmp_path / "site" / "index.html").is_file()


# --- the README is a front door ---------------------------------------------------------------------------------


def test_the_readme_is_a_front_door():
    lines = README.read_text().splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines (at most {MAX_README_LINES}); " \
                                           "move the detail into docs/ and the history into CHANGELOG.md"


def test_the_readme_links_resolve():
    text = README.read_text()
    targets = re.findall(r"\]\(([^)\s]+)\)", text)
    local = [t.split("#")[0] for t in targets if not re.match(r"^[a-z]+:", t) and not t.startswith("#")]
    assert len(local) >= 10
    missing = sorted({t for t in local if t and not (ROOT / t).exists()})
    assert not missing, f"README.md links to files that do not exist: {missing}"


# --- no history outside the CHANGELOG ---------------------------------------------------------------------------

MONTHS = "January|February|March|April|May|June|July|August|September|October|November|December"
HISTORY_PATTERNS: dict[str, re.Pattern[str]] = {
    "an issue number": re.compile(r"(?<![\w/&])#\d+\b|\bissues?\s+#?\d+\b", re.IGNORECASE),
    "a date": re.compile(rf"\b(?:{MONTHS})\s+\d{{1,4}}\b|\b(?:19|20)\d\d-[01]\d-[0-3]\d\b"),
    "a session-relative date": re.compile(
        r"\b(?:the night before|the day before|this stop|the last stop|the previous stop|(?:this|last|previous) session"
        r"|this round|earlier|later still|later the same day|before the fix|after the fix|yesterday|today|tonight"
        r"|this morning|this afternoon|the previous commit)\b", re.IGNORECASE),
    "a commit hash": re.compile(r"\bcommits?\s+(?:at\s+)?[0-9a-f]{7,40}\b|\bat\s+(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b",
                                re.IGNORECASE),
}
"""What marks history in a text, each with what it is called in a failure."""

SOURCE_PACKAGES = ("assets", "batch", "controllers", "envs", "numerics", "pihutil", "rflow", "scripts")
"""The packages whose Python sources the history check reads (not tests/: a test may name what it guards against)."""
SOURCE_HISTORY_PATTERNS: dict[str, re.Pattern[str]] = {
    **HISTORY_PATTERNS,
    "a session-relative date": re.compile(HISTORY_PATTERNS["a session-relative date"].pattern.replace("|earlier|", "|"),
                                          re.IGNORECASE),
    "how the code came to be": re.compile(
        r"\b(?:(?:before|after) this change|development seeds?|traced on|the former (?:python|code|version|one)"
        r"|it replaced|(?:the|a) previous version)\b", re.IGNORECASE),
}
"""`HISTORY_PATTERNS` for the sources, with what narrates how a line of code came to be; "earlier" is left out there:
in code it is the program's own time (an earlier run that --overwrite replaces, a journal's earlier segments, a force
limit hit earlier in the period), not the project's."""
HEX_TOKEN = re.compile(r"(?<![\w.-])(?=[0-9a-f]*\d)[0-9a-f]{7,40}(?![\w-])")
"""A word that may be an abbreviated commit hash (7-40 hex digits, at least one a digit); git decides."""


def known_commits(tokens: Iterable[str], repo: Path = ROOT) -> set[str]:
    """Which of ``tokens`` name a commit of the repository at ``repo`` (empty without git or a repository)."""
    tokens = sorted(set(tokens))
    git = shutil.which("git")
    if not tokens or git is None:
        return set()
    result = subprocess.run([git, "-C", str(repo), "cat-file", "--batch-check"], input="".join(
        f"{t}^{{commit}}\n" for t in tokens), capture_output=True, text=True, timeout=60, check=False)
    if result.returncode != 0:
        return set()
    answers = result.stdout.splitlines()
    return {token for token, answer in zip(tokens, answers) if answer.split()[1:2] == ["commit"]}


def history_markers(paths: Iterable[Path], repo: Path = ROOT,
                    patterns: dict[str, re.Pattern[str]] = HISTORY_PATTERNS) -> list[str]:
    """Every line of ``paths`` that holds history (``patterns``, and hex words that git knows as commits of ``repo``),
    as "FILE:LINE: what: the text"."""
    found, candidates = [], []
    for path in paths:
        for number, line in enumerate(Path(path).read_text().splitlines(), 1):
            where = f"{path}:{number}"
            for what, pattern in patterns.items():
                match = pattern.search(line)
                if match:
                    found.append(f"{where}: {what} ({match.group(0)!r}): {line.strip()}")
            candidates.extend((where, token, line) for token in HEX_TOKEN.findall(line))
    commits = known_commits((token for _, token, _ in candidates), repo)
    found.extend(f"{where}: a commit hash ({token!r}): {line.strip()}" for where, token, line in candidates
                 if token in commits)
    return found


def test_the_history_check_finds_history(tmp_path):
    page = tmp_path / "page.md"
    git = shutil.which("git")
    head = subprocess.run([git, "-C", str(ROOT), "rev-parse", "--short=7", "HEAD"], capture_output=True, text=True,
                          check=False).stdout.strip() if git else ""
    page.write_text("\n".join([
        "Seated 99.3 % on the protocol.",                     # 1: clean
        "As issue #22 asked, and issue 24 too.",              # 2
        "Measured on November 26, then 2026-11-27.",          # 3
        "The night before it was slower; earlier, 129 s.",    # 4
        "Reproduce at commit 54911ff.",                       # 5
        f"The figure of {head or 'abcdef1'}.",                # 6: known to git (when there is git)
        "A rate of 1000000 episodes and 0.0655 N, ab12cd3.",  # 7: hex words git does not know
    ]))
    lines = {int(m.split(":")[1]) for m in history_markers([page])}
    assert {2, 3, 4, 5} <= lines
    assert 1 not in lines and 7 not in lines
    if head:
        assert 6 in lines


def test_no_history_in_the_readme_or_the_docs():
    markers = history_markers(doc_files())
    assert not markers, "history belongs in CHANGELOG.md:\n" + "\n".join(markers)


def source_files() -> list[Path]:
    """Every Python module of `SOURCE_PACKAGES`."""
    return sorted(path for package in SOURCE_PACKAGES for path in (ROOT / package).rglob("*.py"))


def test_the_sources_check_finds_history_but_not_a_program_s_own_time(tmp_path):
    module = tmp_path / "module.py"
    module.write_text("\n".join([
        '"""Stiffness (issue #10), on by default."""',             # 1
        "# Replace an earlier run's outputs; hit earlier: stop.",  # 2: the program's own time
        "# Measured the night before.",                            # 3
        "# (traced on a development seed) the push is halved.",    # 4
        "# It replaced numpy code step for step.",                 # 5
        "color = '#1f77b4'  # noqa: E501",                         # 6
    ]))
    lines = {int(m.split(":")[1]) for m in history_markers([module], patterns=SOURCE_HISTORY_PATTERNS)}
    assert lines == {1, 3, 4, 5}


def test_no_history_in_the_docstrings_and_comments_of_the_sources():
    """Issue numbers, commit hashes, session-relative dates and the story of a change belong in CHANGELOG.md and the
    commit messages; a docstring keeps what the code does and why (the physical reasons, the measured facts)."""
    files = source_files()
    assert len(files) > 150 and ROOT / "envs" / "rollout" / "episode.py" in files
    markers = history_markers(files, patterns=SOURCE_HISTORY_PATTERNS)
    assert not markers, "history belongs in CHANGELOG.md:\n" + "\n".join(markers)
