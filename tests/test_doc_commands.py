"""Every `bin/flaair ...` command line in README.md and docs/**/*.md parses, as written.

Each line of a fenced code block (or an indented one) that starts with `bin/flaair` (a `$ `
prompt allowed) is handed to its command's own parser: the command's `main` runs until its
parser has parsed the line, and stops there (nothing is read, computed or written). A renamed or
removed flag, a misspelt command or an argument a command does not take fails here, naming the
file and line. `bin/flaair run PACKAGE EXECUTABLE` is checked against the packages' entry points
(a tool's own options through its parser; a node's ROS arguments are the node's business). Also
here: every command's `--help` shows each option's default, and the top-level help groups the
commands by job.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import re
import shlex
from collections.abc import Iterator
from pathlib import Path

import pytest

from flaair_common.cli_help import shows_default
from flaair_tools import cli
from test_lab_example import walk_through

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
ENTRY = re.compile(r'"(\w+) = ([\w.]+):(\w+)"')


class Parsed(Exception):
    """Raised by the patched `parse_args` once a parser has parsed its line."""

    def __init__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace) -> None:
        super().__init__(parser.prog)
        self.parser, self.namespace = parser, namespace


ENTRIES = ("parse_args", "parse_known_args", "parse_intermixed_args", "parse_known_intermixed_args")


@contextlib.contextmanager
def parse_only(before: bool = False) -> Iterator[None]:
    """The first parser a command parses its line with raises `Parsed` once it has parsed it
    (the command stops there); with `before`, as soon as it is asked to (its `--help` unread).

    Calls nested inside one parse (subcommands, intermixed parsing) parse as usual; a helper
    parser built without `--help` (one that only peeks at the line) is left alone.
    """
    originals = {name: getattr(argparse.ArgumentParser, name) for name in ENTRIES}
    depth = [0]

    def patched(name: str):
        def call(self, *args, **kwargs):
            if not self.add_help or depth[0]:
                return originals[name](self, *args, **kwargs)
            if before:
                raise Parsed(self, argparse.Namespace())
            depth[0] += 1
            try:
                result = originals[name](self, *args, **kwargs)
            finally:
                depth[0] -= 1
            raise Parsed(self, result[0] if isinstance(result, tuple) else result)

        return call

    for name in ENTRIES:
        setattr(argparse.ArgumentParser, name, patched(name))
    try:
        yield
    finally:
        for name, original in originals.items():
            setattr(argparse.ArgumentParser, name, original)


def entry_points() -> dict[tuple[str, str], str]:
    """(package, executable) -> module of every console script the packages install."""
    found = {}
    for setup in (ROOT / "src").glob("*/setup.py"):
        for name, module, _ in ENTRY.findall(setup.read_text()):
            found[(setup.parent.name, name)] = module
    return found


def parse(words: list[str]) -> tuple[str, argparse.ArgumentParser | None]:
    """('', parser) when `bin/flaair WORDS...` parses; (the parser's complaint, None) otherwise."""
    if len(words) < 2:
        return "no command", None
    name, rest = words[1], words[2:]
    if name == "run":
        if len(rest) < 2:
            return "run needs PACKAGE EXECUTABLE", None
        module = entry_points().get((rest[0], rest[1]))
        if module is None:
            return f"no executable {rest[1]!r} in package {rest[0]!r}", None
        if rest[1].endswith("_node") or rest[1] == "container":
            return "", None  # a node: --ros-args and --help are rclpy's and the node's
        module_name, rest = module, rest[2:]
    elif name not in cli.SUBCOMMANDS:
        return f"unknown command {name!r}", None
    else:
        module_name = cli.SUBCOMMANDS[name][0]
    module = importlib.import_module(module_name)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), parse_only():
        try:
            module.main(rest)
        except Parsed as parsed:
            return "", parsed.parser
        except SystemExit as exit_:
            if exit_.code in (0, None):
                return "", None  # --help
            return (err.getvalue() or out.getvalue()).strip() or f"exit {exit_.code}", None
    return "the command returned before its parser parsed the line", None


def command_lines(path: Path) -> Iterator[tuple[int, list[str]]]:
    """(line number, words) of each `bin/flaair` line in the file's code blocks."""
    lines = path.read_text(encoding="utf-8").split("\n")
    fenced, i = False, 0
    while i < len(lines):
        line, number = lines[i], i + 1
        if line.lstrip().startswith("```"):
            fenced = not fenced
            i += 1
            continue
        text = line.strip()
        in_block = fenced or line.startswith("    ")
        if text.startswith("$ "):
            text = text[2:]
        if not (in_block and text.startswith("bin/flaair ")):
            i += 1
            continue
        while text.endswith("\\") and i + 1 < len(lines):  # continued lines
            i += 1
            text = text[:-1] + " " + lines[i].strip()
        words = shlex.split(text, comments=True)
        while words and words[-1] in ("&", "&&", ";"):
            words.pop()
        yield number, words
        i += 1


def all_command_lines() -> list[tuple[str, int, list[str]]]:
    return [
        (str(path.relative_to(ROOT)), number, words)
        for path in DOCS
        for number, words in command_lines(path)
    ]


@pytest.mark.timeout(60)
def test_every_command_line_in_the_docs_parses() -> None:
    lines = all_command_lines()
    assert len(lines) > 50, "the extraction found too few command lines"
    assert {"README.md", "docs/USAGE.md", "docs/DISCREPANCY.md"} <= {f for f, _, _ in lines}
    failures = []
    for path, number, words in lines:
        problem, _ = parse(words)
        if problem:
            failures.append(f"{path}:{number}: {shlex.join(words)}\n    {problem}")
    assert not failures, "command lines the parser refuses:\n" + "\n".join(failures)


@pytest.mark.timeout(30)
def test_a_renamed_flag_fails_the_check() -> None:
    assert parse(["bin/flaair", "import", "a.csv", "--out", "b"])[0] == ""
    assert (
        "unrecognized arguments: --outdir"
        in parse(["bin/flaair", "import", "a.csv", "--out", "b", "--outdir", "c"])[0]
    )
    assert parse(["bin/flaair", "imprt", "a.csv"])[0] == "unknown command 'imprt'"
    assert "no executable" in parse(["bin/flaair", "run", "flaair_sim", "plant"])[0]
    # the old name of --rest-s keeps working
    assert parse(["bin/flaair", "import", "a.csv", "--gap-s", "1", "--out", "b"])[0] == ""


def command_parsers() -> Iterator[tuple[str, argparse.ArgumentParser]]:
    """Every `bin/flaair` command's parser, and each of its subcommands' parsers."""
    extra = {  # commands that hand some lines to another parser
        "identify": [
            ["--table", "t.csv", "--out", "o"],
            ["r.csv", "--table", "t.csv", "--out", "o"],
        ],
        "discrepancy": [
            ["--table", "t.csv", "--out", "o"],
            ["r.csv", "--table", "t.csv", "--out", "o"],
        ],
    }
    for name in cli.SUBCOMMANDS:
        for argv in [["--help"], *extra.get(name, [])]:
            parser = capture(cli.SUBCOMMANDS[name][0], argv)
            yield from walk(f"{name} {' '.join(argv)}", parser)


def capture(module_name: str, argv: list[str]) -> argparse.ArgumentParser:
    """The parser `main(argv)` builds, taken before it parses."""
    module = importlib.import_module(module_name)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), parse_only(True):
        try:
            module.main(argv)
        except Parsed as parsed:
            return parsed.parser
    raise AssertionError(f"{module_name}.main({argv}) built no parser: {err.getvalue()}")


def walk(
    label: str, parser: argparse.ArgumentParser
) -> Iterator[tuple[str, argparse.ArgumentParser]]:
    yield label, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for verb, sub in action.choices.items():
                yield from walk(f"{label} {verb}", sub)


@pytest.mark.timeout(60)
def test_every_option_of_every_command_shows_its_default() -> None:
    missing = []
    for label, parser in command_parsers():
        formatter = parser._get_formatter()
        for action in parser._actions:
            if not action.option_strings or action.help == argparse.SUPPRESS:
                continue
            if isinstance(action, argparse._HelpAction | argparse._VersionAction):
                continue
            text = formatter._get_help_string(action)
            if not shows_default(text):
                missing.append(f"{label}: {'/'.join(action.option_strings)}: {text!r}")
    assert not missing, "options whose --help does not say the default:\n" + "\n".join(missing)


@pytest.mark.timeout(30)
def test_identify_and_discrepancy_show_table_in_their_usage() -> None:
    # runs, bags and tables in any mix, told apart by content; --table names one explicitly
    for name in ("identify", "discrepancy"):
        parser = capture(cli.SUBCOMMANDS[name][0], ["--help"])
        usage = parser.format_usage()
        assert "INPUT ..." in usage and "frequency-response table" in usage, usage
        assert "--table" in parser.format_help()


@pytest.mark.timeout(30)
def test_the_top_level_help_groups_every_command_by_job() -> None:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert cli.main(["--help"]) == 0
    text = out.getvalue()
    titles = [title for title, _ in cli.GROUPS]
    assert [t for t in titles if f"\n{t}:\n" in text] == titles
    positions = [text.index(f"\n{t}:\n") for t in titles]
    assert positions == sorted(positions)
    for name in [*cli.SUBCOMMANDS, "run"]:
        assert re.search(rf"^  {re.escape(name)} ", text, re.M), name
    bench = text.split(f"\n{titles[0]}:\n", 1)[1].split("\n\n", 1)[0]
    assert "  live " in bench and "  topic " not in bench
    assert "docs/GLOSSARY.md" in text


@pytest.mark.timeout(30)
def test_epilog_example_lines_fit_a_terminal_and_are_not_rewrapped() -> None:
    long_lines = []
    for label, parser in command_parsers():
        for line in parser.format_help().split("\n"):
            if line.lstrip().startswith("bin/flaair") and len(line) > 100:
                long_lines.append(f"{label}: {line}")
        for text in (parser.description or "", parser.epilog or ""):
            if "bin/flaair" in text:
                assert all(line in parser.format_help() for line in text.split("\n") if line), label
    assert not long_lines, "\n".join(long_lines)


TERMS = ("dSA", "K_r", "lockstep", "vocabulary", "discovered", "held-out", "Hopf", "V_HREF")


@pytest.mark.timeout(60)
def test_a_help_that_uses_a_glossary_term_points_to_the_glossary() -> None:
    unexplained = []
    for label, parser in command_parsers():
        text = parser.format_help()
        used = [t for t in TERMS if re.search(rf"(?<![\w-]){re.escape(t)}(?![\w-])", text)]
        subcommand = "--help " in label  # `topic --help echo`: the verb's own help
        if used and "docs/GLOSSARY.md" not in text and not subcommand:
            unexplained.append(f"{label}: {used}")
    assert not unexplained, "helps using terms without docs/GLOSSARY.md:\n" + "\n".join(unexplained)


LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


@pytest.mark.timeout(30)
def test_every_relative_link_in_the_docs_names_a_file_that_exists() -> None:
    broken = []
    for path in DOCS:
        for target in LINK.findall(path.read_text(encoding="utf-8")):
            if "://" in target or target.startswith("mailto:"):
                continue
            if not (path.parent / target).exists():
                broken.append(f"{path.relative_to(ROOT)}: {target}")
    assert not broken, "links to nothing:\n" + "\n".join(broken)


@pytest.mark.timeout(30)
def test_the_readme_quickstart_is_the_tested_walk_through() -> None:
    """README's four commands are docs/LAB_FILES.md's walk-through (run as written by
    tests/test_lab_example.py), in order, writing apart; the output shown is theirs.
    """
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    quick = text.split("## Quickstart", 1)[1].split("\n## ", 1)[0]
    commands = [words for _, words in command_lines_of(quick)]
    assert [c[1] for c in commands] == ["import", "calibrate", "analyze", "discrepancy"]
    tested = walk_through()
    assert all(c in tested for c in commands), "README's quickstart left the walk-through"
    assert [tested.index(c) for c in commands] == sorted(tested.index(c) for c in commands)
    outs = [c[c.index("--out") + 1] for c in commands]
    assert len(set(outs)) == 4 and outs[0] in commands[1] and outs[1] in " ".join(commands[2])
    shown = " ".join(quick.split())
    assert (
        "run01: 10000 samples at 5000 Hz (first_sample_index 0) from "
        "examples/lab_session/run01.mat; video 2000 fps, 800 frames (99.0 % tracked), 800 "
        "placed, 0 outside the log; trigger at 0.800000 s; video vs stroke sensor +0.016 ms "
        "(correlation +0.999)"
    ) in shown
    assert "efficiency=0.23" in shown  # the strain transfer the walk-through test checks


def command_lines_of(text: str) -> Iterator[tuple[int, list[str]]]:
    """(line number, words) of each one-line `bin/flaair` command in the text's code blocks."""
    lines = text.split("\n")
    fenced = False
    for number, line in enumerate(lines, 1):
        if line.startswith("```"):
            fenced = not fenced
        elif fenced and line.startswith("bin/flaair "):
            yield number, shlex.split(line, comments=True)
