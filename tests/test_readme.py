"""The README and ARCHITECTURE.md say what the code does: the command synopsis, the output files,
one account of unreadable images, and no design document outside the repository."""

import re

import click
import pytest
from conftest import REPO_ROOT

from pld_slam.io.run_output import RUN_FILES, RUN_LOCK
from pld_slam.synth import write_sequence
from pld_slam_cli.main import cli

README = (REPO_ROOT / "README.md").read_text()
ARCHITECTURE = (REPO_ROOT / "ARCHITECTURE.md").read_text()


def section(markdown: str, heading: str) -> str:
    """The text under the ``## heading`` line of ``markdown``, up to the next ``## `` heading."""
    return markdown.split(f"\n## {heading}\n", 1)[1].split("\n## ", 1)[0]


def commands(group: click.Group, ctx: click.Context, prefix: tuple[str, ...] = ()):
    """``(name words, command)`` of every leaf command under ``group`` (loaded through `get_command`)."""
    for name in group.list_commands(ctx):
        command = group.get_command(ctx, name)
        if isinstance(command, click.Group):
            yield from commands(command, ctx, (*prefix, name))
        else:
            yield (*prefix, name), command


LEAF_COMMANDS = list(commands(cli, click.Context(cli)))


def synopsis_lines(words: tuple[str, ...]) -> list[str]:
    """The lines of the "Command line" code block for the command ``words``, its main form first."""
    block = section(README, "Command line").split("```", 2)[1]
    start = "pld-slam " + " ".join(words)
    return [line for line in block.splitlines() if line == start or line.startswith(start + " ")]


def bracket_depth(line: str, position: int) -> int:
    """How many ``[`` are open at ``position`` of ``line``."""
    return line[:position].count("[") - line[:position].count("]")


@pytest.mark.parametrize("words, command", LEAF_COMMANDS, ids=[" ".join(words) for words, _ in LEAF_COMMANDS])
def test_the_synopsis_shows_every_option_optional_ones_in_brackets_and_every_choice(words, command):
    """Each option of the command's ``--help`` is on one of its synopsis lines; on the first
    line (the main form; ``ablate --report DIR`` is a second form) an optional one is in
    brackets and a required one is not. A choice option lists exactly its choices."""
    lines = synopsis_lines(words)
    assert lines, f"no synopsis line for pld-slam {' '.join(words)}"
    for option in (param for param in command.params if isinstance(param, click.Option)):
        name = max(option.opts, key=len)
        found = [(line, match) for line in lines for match in re.finditer(rf"{name}(?![\w-])", line)]
        assert found, f"pld-slam {' '.join(words)}: {name} missing from the synopsis"
        line, match = found[0]
        if line == lines[0]:
            assert (bracket_depth(line, match.start()) == 0) == option.required, f"{name}: brackets"
        if isinstance(option.type, click.Choice):
            shown = line[match.end():].split()[0].rstrip("]")
            assert set(shown.split("|")) == set(option.type.choices), f"{name}: choices {shown}"


def output_rows() -> list[tuple[list[str], str]]:
    """``(file names, written-by cell)`` of each row of the "Output files" table."""
    rows = []
    for line in section(README, "Output files").splitlines():
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        if line.startswith("| `"):
            rows.append((re.findall(r"`([^`]+)`", cells[0]), cells[1]))
    return rows


def test_the_output_table_lists_exactly_the_files_run_writes_and_those_of_eval_plot():
    by_run = {name for names, writer in output_rows() if writer.startswith("`run") for name in names}
    by_eval = {name for names, writer in output_rows() if writer.startswith("`eval --plot") for name in names}
    # the files of the run's folder (the lock and a kept partial trajectory are not among those a run deletes
    # first), and the recording --rerun names
    assert by_run == {*RUN_FILES, RUN_LOCK, "trajectory.partial.N.tum.txt", "FILE.rrd"}
    assert by_eval == {"trajectory_top_view.png", "ate_over_time.png"}


def test_the_readme_says_one_thing_about_unreadable_images_the_run_skips_them():
    sentences = re.split(r"(?<=[.;])\s+", " ".join(README.split()))
    about = [sentence for sentence in sentences if "unreadable image" in sentence]
    assert about
    assert all("skipped" in sentence and "stop" not in sentence for sentence in about), about


def test_the_docs_point_inside_the_repository_and_architecture_has_the_conventions():
    for text in (README, ARCHITECTURE):
        assert not re.search(r"\.\./[\w./-]*\.md", text), "a document outside the repository"
    assert "ARCHITECTURE.md" in section(README, "Conventions")
    conventions = " ".join(section(ARCHITECTURE, "Conventions").split())
    for sentence in re.split(r"(?<=\.)\s+", " ".join(section(README, "Conventions").split())):
        if "ARCHITECTURE.md" not in sentence:
            assert sentence in conventions
    assert "\n## One run\n" in ARCHITECTURE  # the flow of one run, through the module map


def test_the_python_api_example_runs_and_prints_the_ate_and_the_map(tmp_path, monkeypatch, capsys):
    example = section(README, "Python API").split("```python\n", 1)[1].split("```", 1)[0]
    write_sequence(tmp_path / "runs" / "demo" / "sequence", "static", 12, (320, 240), seed=0)
    monkeypatch.chdir(tmp_path)
    exec(compile(example, "README.md (Python API)", "exec"), {})
    ate, counts = capsys.readouterr().out.splitlines()
    assert re.fullmatch(r"ATE 0\.\d{3} m", ate) and float(ate.split()[1]) < 0.2
    points, lines, keyframes = (int(word) for word in re.findall(r"\d+", counts))
    assert points > 100 and lines > 10 and keyframes >= 2
