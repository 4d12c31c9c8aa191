"""Every command line the READMEs and the quickstart notebook show still parses: each
``key=value`` names a key its command takes, and, for the package's commands, holds a value of
that key's type; and every Python call they show of the package passes keywords it takes. A
key or parameter renamed in the code and left in a document fails here."""

from __future__ import annotations

import ast
import contextlib
import dataclasses
import importlib
import inspect
import io
import json
import os
import re
import shlex

import pytest

from admissable_jax.audit.command import AuditConfig
from admissable_jax.cli import parse_args
from admissable_jax.config import ExperimentConfig, TrainConfig, config_file_of
from admissable_jax.export import ExportConfig
from admissable_jax.plot import PlotConfig
from admissable_jax.rollout import RolloutConfig
from admissable_jax.status import StatusConfig
from admissable_jax.video import VideoConfig

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
DOCUMENTS = ("README.md", "benchmarks/README.md", "notebooks/quickstart.ipynb")
COMMANDS = {"train": TrainConfig, "experiment": ExperimentConfig, "plot": PlotConfig, "audit": AuditConfig,
            "video": VideoConfig, "export": ExportConfig, "rollout": RolloutConfig, "status": StatusConfig}
PATHS_ONLY = ("compact_pngs", "load_policy_memory")  # scripts that take paths, no keys
# A command line: `python -m admissable_jax.<command>` (or `python -m admissable_jax <command>`)
# or `python benchmarks/<script>.py`, then its items up to the end of the line, a closing
# backtick or a table's bar (" | "; a bar inside a table's cell, "\|", reads "one or the
# other": env=hopper|ant).
COMMAND_LINE = re.compile(rf"python3? (?:-m admissable_jax(?:\.| (?=(?:{'|'.join(COMMANDS)})\b))(\w+)|"
                          r"benchmarks/(\w+)\.py)(.*?)(?=`|\n| \| |$)")
# A value standing for one's own (DIR, RUN_DIR, S, <run>, ...), not a value to parse.
PLACEHOLDER = re.compile(r"^(<[^>]*>|[A-Z][A-Z_]*)(/.*)?$|\.\.\.")


def commands_in(text: str) -> list[tuple[str, list[str]]]:
    """(command or script, its words) of each command line in ``text``: lines continued by a
    backslash joined, split as a shell does, a ``# comment`` left out, ``[optional]`` items kept."""
    return [(match.group(1) or match.group(2), shlex.split(match.group(3).replace("[", " ").replace("]", " "), comments=True))
            for match in COMMAND_LINE.finditer(text.replace("\\\n", " ").replace("\\|", "|"))]


def notebook_cells() -> list[dict]:
    """The quickstart notebook's cells."""
    with open(os.path.join(ROOT, "notebooks", "quickstart.ipynb")) as file:
        return json.load(file)["cells"]


def documented_commands() -> list[tuple[str, str, list[str]]]:
    """(document, command, words) of every command line the documents show."""
    found = []
    for document in DOCUMENTS:
        if document.endswith(".ipynb"):
            text = "\n".join("".join(cell["source"]) for cell in notebook_cells())
        else:
            with open(os.path.join(ROOT, document)) as file:
                text = file.read()
        found += [(document, command, words) for command, words in commands_in(text)]
    return found


def keys_of(command: str, verb: str | None) -> set[str]:
    """The keys ``command`` takes: a package command's config's, or a benchmark script's
    (campaign.py: its verb's)."""
    if command in COMMANDS:
        return {field.name for field in dataclasses.fields(COMMANDS[command])} | (
            {"config"} if command in ("train", "experiment") else set())  # settings from a file (config_file_of)
    module = importlib.import_module(command)  # benchmarks/ is on the tests' path (conftest.py)
    configs = [module.VERBS[verb][0]] if command == "campaign" else [
        value for name, value in vars(module).items()
        if name.endswith("Config") and dataclasses.is_dataclass(value) and value.__module__ == module.__name__]
    return {field.name for config in configs for field in dataclasses.fields(config)}


def problem_of(command: str, words: list[str]) -> str | None:
    """What is wrong with a shown command line: a key its command does not take, or (a package
    command) a value its key's type refuses; None where it parses."""
    verb = words[0] if command == "campaign" and words else None
    items = [word for word in words if "=" in word]
    unknown = [item for item in items if item.split("=", 1)[0] not in keys_of(command, verb)]
    if unknown:
        return f"{unknown[0]!r} names no key of {command}"
    if command in COMMANDS:
        given = [item for item in items if not PLACEHOLDER.search(item.split("=", 1)[1]) and not item.startswith("config=")]
        said = io.StringIO()
        try:
            with contextlib.redirect_stderr(said):
                parse_args(COMMANDS[command], given, command, "", config_file=(
                    config_file_of(COMMANDS[command]) if command in ("train", "experiment") else None))
        except SystemExit:
            return said.getvalue().strip()
    return None


def test_every_documented_command_line_parses(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # relative outs (resume=auto, resume=true read them) name no run of one's own
    commands = [(document, command, words) for document, command, words in documented_commands()
                if command not in PATHS_ONLY]
    assert {"train", "experiment", "plot", "audit", "video", "export", "rollout", "status", "campaign", "figure1", "scoring_round"} <= {
        command for _, command, _ in commands}
    assert len(commands) >= 120, len(commands)
    for document, command, words in commands:
        problem = problem_of(command, words)
        assert problem is None, f"{document}: {command} {' '.join(words)}: {problem}"


@pytest.mark.parametrize("line, problem", [
    ("python -m admissable_jax.train env=hopper total_step=5", "'total_step=5' names no key of train"),
    ("python -m admissable_jax experiment env=hopper seed=5", "'seed=5' names no key of experiment"),
    ("python -m admissable_jax.audit DIR k=1 episodes=ten", "error: bad value for 'episodes': Value 'ten' of type 'str' "
                                                            "could not be converted to Integer"),
    ("python benchmarks/scoring_round.py env=hopper episodes=10", "'episodes=10' names no key of scoring_round"),
    ("python benchmarks/campaign.py plan env=hopper trace_dir=x", "'trace_dir=x' names no key of campaign"),
])
def test_a_stale_command_line_is_found(line, problem):
    """The check above, on command lines a document could hold."""
    ((command, words),) = commands_in(f"```bash\n{line}\n```\n")
    assert problem_of(command, words) == problem


def python_blocks() -> list[tuple[str, str]]:
    """(document, code) of every Python block the README shows and every code cell of the quickstart."""
    with open(os.path.join(ROOT, "README.md")) as file:
        blocks = [("README.md", code) for code in re.findall(r"```python\n(.*?)```", file.read(), re.S)]
    return blocks + [("quickstart.ipynb", "".join(cell["source"])) for cell in notebook_cells() if cell["cell_type"] == "code"]


def test_every_documented_python_call_names_real_parameters():
    """The README's and the quickstart's Python: each name imported from admissable_jax is
    there, and each call of one (in that block or a later one of the document) passes
    keywords its signature takes (a function that hands ``**env_kwargs`` on to Gymnasium
    takes any: those are the env's to check)."""
    calls, imported = 0, {}
    for document, code in python_blocks():
        for node in ast.walk(ast.parse(code)):
            if isinstance(node, ast.ImportFrom) and node.module.split(".")[0] == "admissable_jax":
                module = importlib.import_module(node.module)
                for alias in node.names:
                    assert hasattr(module, alias.name), f"{document}: {node.module} has no {alias.name}"
                    imported[alias.asname or alias.name] = getattr(module, alias.name)
        for node in ast.walk(ast.parse(code)):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in imported:
                parameters = inspect.signature(imported[node.func.id]).parameters
                takes_any = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values())
                for keyword in node.keywords:
                    assert keyword.arg is None or keyword.arg in parameters or takes_any, (
                        f"{document}: {node.func.id}() takes no {keyword.arg}=")
                calls += 1
    assert calls >= 15, calls


def test_every_link_to_a_section_leads_to_one():
    """The documents' links within themselves (``[...](#anchor)``, the README's *Where to
    look*) name a heading's anchor as GitHub makes it: lower case, punctuation dropped, spaces
    as hyphens."""
    for document in ("README.md", "benchmarks/README.md"):
        with open(os.path.join(ROOT, document)) as file:
            text = file.read()
        headings = re.findall(r"^#{1,6} (.+)$", re.sub(r"```.*?```", "", text, flags=re.S), re.M)
        anchors = {re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-") for heading in headings}
        links = re.findall(r"\]\(#([^)]+)\)", text)
        assert document != "README.md" or len(links) >= 15, len(links)
        broken = [link for link in links if link not in anchors]
        assert not broken, f"{document}: links to no section: {broken}"
