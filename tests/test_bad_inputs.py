"""docs/bad-inputs.md lists hand-written bad inputs and what the CLI answers to each; this test runs every row
and compares the exit status and the message with the table, so the table always shows what users see.

Each row's command runs in-process (``tissuerender.cli.main``) against a copy of ``tests/bad_inputs/`` (plus
the binary files ``binary_files`` writes), whose path the table shows as ``{tmp}``. The message column is
the line that says what went wrong: the only line of a tissuerender error, argparse's last line (it prints
its usage first), a traceback's last line (compared on its exception type only), or, for a command that
succeeds, the last line it prints.

A second test holds every row to the standard (exit status 2, one line naming the file or argument at
fault, no traceback): a row whose notes begin with ``bug`` is expected to fail it (xfail, strict, so the
mark has to go once the bug is fixed), and a row whose notes begin with ``accepted`` is expected to succeed.

When messages change on purpose, rewrite the exit and message columns from the CLI's actual output:

    python -m tests.test_bad_inputs --write        # or: TISSUERENDER_UPDATE_BAD_INPUTS=1 pytest tests/test_bad_inputs.py

(the command, input and notes columns are kept; check the diff, and update a row's notes when a bug is fixed).
"""
from __future__ import annotations

import contextlib
import hashlib
import io
import os
import re
import shlex
import shutil
import sys
import tempfile
import traceback
import warnings
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TABLE = ROOT / "docs" / "bad-inputs.md"
INPUTS = ROOT / "tests" / "bad_inputs"
PLACEHOLDER = "{tmp}"
HEADER = "| command | input | exit | message | notes |"
UPDATE = os.environ.get("TISSUERENDER_UPDATE_BAD_INPUTS") == "1"


@dataclass(frozen=True)
class Row:
    command: str   # arguments after `tissuerender`, with {tmp}
    input: str     # what is wrong, for a reader
    exit: str      # exit status as text ("2")
    message: str   # the message line, with {tmp}
    notes: str


@dataclass(frozen=True)
class Outcome:
    status: int
    message: str
    stderr: str    # whole stderr (paths normalised), for the standard check
    traceback: bool


CODE_COLUMNS = (0, 3)  # command and message: code spans, compared verbatim


def _cells(line: str) -> list[str]:
    """The cells of a Markdown table row; ``\\|`` is a literal bar; the command and message lose the
    backticks of their code span."""
    parts = re.split(r"(?<!\\)\|", line.strip())[1:-1]
    cells = []
    for i, part in enumerate(parts):
        text = part.strip()
        match = re.fullmatch(r"(`+) ?(.*?) ?\1", text) if i in CODE_COLUMNS else None
        cells.append((match.group(2) if match else text).replace("\\|", "|"))
    return cells


def _code(text: str) -> str:
    """``text`` as a Markdown code span in a table cell (a fence longer than any backtick run inside)."""
    if not text:
        return ""
    fence = "`" * (max((len(run) for run in re.findall(r"`+", text)), default=0) + 1)
    pad = " " if "`" in text else ""
    return f"{fence}{pad}{text.replace('|', chr(92) + '|')}{pad}{fence}"


def read_table(text: str) -> tuple[str, list[Row], str]:
    """(text before the table, its rows, text after it)."""
    lines = text.splitlines(keepends=True)
    start = next(i for i, line in enumerate(lines) if line.strip() == HEADER)
    end = start + 2
    while end < len(lines) and lines[end].startswith("|"):
        end += 1
    rows = [Row(*_cells(line)) for line in lines[start + 2:end]]
    return "".join(lines[:start]), rows, "".join(lines[end:])


def format_row(row: Row) -> str:
    notes = row.notes.replace("|", "\\|")
    return (f"| {_code(row.command)} | {row.input.replace('|', chr(92) + '|')} | {row.exit} | "
            f"{_code(row.message)} | {notes} |\n")


def write_table(before: str, rows: list[Row], after: str) -> str:
    return before + HEADER + "\n|---|---|---|---|---|\n" + "".join(format_row(r) for r in rows) + after


def binary_files(folder: Path) -> None:
    """The inputs that are not text: fixed pseudo-random bytes named as a tet mesh, a surface and a scene."""
    garbage = b"".join(hashlib.sha512(f"bad input {k}".encode()).digest() for k in range(8))  # 512 bytes, same everywhere
    (folder / "garbage.msh").write_bytes(garbage)
    (folder / "garbage.stl").write_bytes(garbage)
    (folder / "binary.toml").write_bytes(b"\x00\x01TOML?" + garbage)


def prepare(folder: Path) -> Path:
    """A fresh copy of tests/bad_inputs/ with the binary files; returns the folder the table calls {tmp}."""
    shutil.copytree(INPUTS, folder, dirs_exist_ok=True)
    binary_files(folder)
    return folder


def _normalise(text: str, folder: Path) -> str:
    for form in sorted({str(folder.resolve()), str(folder)}, key=len, reverse=True):
        text = text.replace(form, PLACEHOLDER)
    return text


def run(command: str, folder: Path) -> Outcome:
    """Run one row's command as `tissuerender` would, in-process: exit status and what it printed."""
    from tissuerender.cli import main

    argv = shlex.split(command.replace(PLACEHOLDER, str(folder)))
    out, err = io.StringIO(), io.StringIO()
    crashed = False
    with warnings.catch_warnings(record=True) as caught, contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        warnings.simplefilter("default")
        try:
            status = main(argv)
        except SystemExit as e:  # argparse
            status = e.code if isinstance(e.code, int) else 1
        except Exception:  # Python would print the traceback and exit with status 1
            traceback.print_exc(file=err)
            status, crashed = 1, True
    shown = "".join(warnings.formatwarning(w.message, w.category, w.filename, w.lineno) for w in caught)
    stderr = _normalise(shown + err.getvalue(), folder)
    stdout = _normalise(out.getvalue(), folder)
    lines = [line for line in (stderr or stdout).splitlines() if line.strip()]
    return Outcome(status, lines[-1].strip() if lines else "", stderr, crashed)


def run_in_copy(command: str, workdir: Path) -> Outcome:
    """``run`` against a fresh copy of the inputs in a new folder under ``workdir``, so no row sees another's
    output (the test's workers and ``--write`` may run the rows in any order)."""
    return run(command, prepare(Path(tempfile.mkdtemp(prefix="row_", dir=workdir))))


def regenerate(workdir: Path) -> tuple[str, str]:
    """(the table's current text, the text with every row's exit and message from the CLI)."""
    text = TABLE.read_text()
    before, rows, after = read_table(text)
    outcomes = {row.command: run_in_copy(row.command, workdir) for row in rows}
    fresh = [Row(r.command, r.input, str(outcomes[r.command].status), outcomes[r.command].message, r.notes)
             for r in rows]
    return text, write_table(before, fresh, after)


ROWS = read_table(TABLE.read_text())[1]


@pytest.fixture(scope="session")
def outcome_of(tmp_path_factory):
    """Each row's outcome, run once per test process (both tests of a row share it)."""
    workdir, cache = tmp_path_factory.mktemp("bad_inputs"), {}

    def get(row: Row) -> Outcome:
        if row.command not in cache:
            cache[row.command] = run_in_copy(row.command, workdir)
        return cache[row.command]

    return get


def _agrees(row: Row, outcome: Outcome) -> bool:
    """The row shows this outcome. For a traceback (a bug row) only the exception's type is compared: its
    text can depend on the CPU and the linear-algebra library (``LinAlgError: Eigenvalues did not converge``)."""
    if row.exit != str(outcome.status):
        return False
    if outcome.traceback:
        return row.message.split(":")[0] == outcome.message.split(":")[0]
    return row.message == outcome.message


@pytest.mark.parametrize("row", ROWS, ids=[r.command for r in ROWS])
def test_table_row_matches_what_the_cli_prints(row, outcome_of):
    if UPDATE:
        return  # test_rewrite_the_table rewrites it
    outcome = outcome_of(row)
    cli = Row(row.command, row.input, str(outcome.status), outcome.message, row.notes)
    assert _agrees(row, outcome), ("docs/bad-inputs.md differs from the CLI's output (rewrite it with "
                                   "`python -m tests.test_bad_inputs --write` if the change is intended):\n"
                                   f"  table: {format_row(row).rstrip()}\n  cli:   {format_row(cli).rstrip()}")


if UPDATE:
    def test_rewrite_the_table(tmp_path):
        text, fresh = regenerate(tmp_path)
        if fresh != text:
            TABLE.write_text(fresh)


def test_table_has_twenty_rows_across_the_commands():
    commands = {shlex.split(r.command)[0] for r in ROWS}
    assert len(ROWS) >= 20 and {"render", "plan", "validate", "lookdev", "golden"} <= commands
    assert len({r.command for r in ROWS}) == len(ROWS), "each command once (the outcomes are keyed by it)"


def _case(row: Row):
    marks = [pytest.mark.xfail(strict=True, reason=row.notes)] if row.notes.lower().startswith("bug") else []
    return pytest.param(row, marks=marks, id=row.command)


@pytest.mark.parametrize("row", [_case(r) for r in ROWS])
def test_bad_input_gets_one_line_naming_what_is_wrong(row, outcome_of):
    outcome = outcome_of(row)
    if row.notes.lower().startswith("accepted"):
        assert outcome.status == 0 and not outcome.traceback, outcome
        return
    assert not outcome.traceback and outcome.status == 2, outcome
    lines = outcome.stderr.splitlines()
    if lines and lines[0].startswith("usage: "):  # argparse: its usage (maybe wrapped), then one line naming the argument
        assert ": error: " in lines[-1] and not any("error" in line for line in lines[:-1]), outcome.stderr
        return
    assert len(lines) == 1 and lines[0].startswith("error: "), outcome.stderr
    named = [a for a in shlex.split(row.command)[1:] if a in outcome.message or a.split("=")[0] in outcome.message]
    assert named or f"{PLACEHOLDER}/" in outcome.message, f"names neither a file nor an argument: {outcome.message}"


def main(argv: list[str]) -> int:
    if argv not in ([], ["--write"]):
        print("usage: python -m tests.test_bad_inputs [--write]", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="bad_inputs_") as tmp:
        text, fresh = regenerate(Path(tmp))
    if fresh == text:
        print(f"{TABLE.relative_to(ROOT)} matches the CLI's output")
        return 0
    if argv == ["--write"]:
        TABLE.write_text(fresh)
        print(f"rewrote {TABLE.relative_to(ROOT)}")
        return 0
    print(f"{TABLE.relative_to(ROOT)} differs from the CLI's output; rerun with --write to rewrite it")
    return 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
