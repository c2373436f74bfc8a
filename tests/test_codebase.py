"""The codebase's own rules, checked on every test run (ARCHITECTURE.md, "Rules of the tree").

- The product speaks of the product: no sentence in the product, its tests, benchmarks or docs
  refers to the history of its development (history lives in git, ``CHANGELOG.md`` and
  ``docs/DECISIONS.md``).
- No Python file over ``MAX_FILE_LINES`` lines, no function over ``MAX_FUNCTION_LINES`` lines,
  except those listed with a reason in ``pyproject.toml`` (``[tool.wrinkles.long-functions]``).
- Tests do not import ``benchmarks``; numeric comparisons use ``np.testing`` (it says what
  differs), not a bare ``assert np.allclose``.
- The maps stay short: ``ARCHITECTURE.md`` and ``docs/BENCHMARKS.md`` within their line budgets.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
CODE_DIRS = ("sim", "learn", "pipelines", "usd_io", "tests", "benchmarks", "tools")
WORDING_DIRS = ("sim", "learn", "pipelines", "usd_io", "tests", "benchmarks", "docs")
WORDING_FILES = ("README.md", "ARCHITECTURE.md")
HISTORY_FILES = ("docs/DECISIONS.md", "CHANGELOG.md")  # where history belongs
TEXT_SUFFIXES = {".py", ".md", ".toml", ".txt", ".sh", ".json", ".cfg", ".yaml", ".yml"}
MAX_FILE_LINES = 800
MAX_FUNCTION_LINES = 80
DOC_BUDGETS = {"ARCHITECTURE.md": 250, "docs/BENCHMARKS.md": 300}

# Phrases that narrate the development of the code rather than say what it does. Each is a
# pattern a reader would recognise as history: "session 40", "issue 3", "(was 50 mm",
# "10 mm until session 9", "previously", "the old default".
HISTORY_PATTERNS = [
    r"\bsessions? \d",
    r"\bissues? #?\d",
    r"\buntil (?:session|issue|commit|v?\d)",
    r"\b(?:was|were) (?:[^.;:\n]|\.(?=\d)){0,60}\buntil\b",
    r"\(was\b",
    r"\bpreviously\b",
    r"\bformerly\b",
    r"\bused to be\b",
    r"\btried and (?:removed|dropped|reverted|abandoned)\b",
    r"\bthe old (?:run|runs|default|defaults|code|system|floor|layout|value)\b",
    r"\bbefore the change\b",
    r"\bsince (?:session|issue|commit)\b",
]
HISTORY = re.compile("|".join(HISTORY_PATTERNS), re.IGNORECASE)
# file names that carry the history of a run: "plan_s53_a.txt", "session12.json", "issue3_bench.py"
HISTORY_NAME = re.compile(r"(?:^|[_\-.])s\d{2}(?:[_\-.]|$)|session|issue\d", re.IGNORECASE)


def _tracked_files(dirs, files=()) -> list[Path]:
    out = [ROOT / f for f in files if (ROOT / f).is_file()]
    for d in dirs:
        out += [p for p in sorted((ROOT / d).rglob("*")) if p.is_file() and "__pycache__" not in p.parts]
    return out


def _rel(p: Path) -> str:
    return p.relative_to(ROOT).as_posix()


def _wording_files() -> list[Path]:
    skip = {ROOT / f for f in HISTORY_FILES} | {Path(__file__).resolve()}
    return [p for p in _tracked_files(WORDING_DIRS, WORDING_FILES)
            if p.suffix in TEXT_SUFFIXES and p not in skip]


def history_phrases(text: str) -> list[tuple[int, str]]:
    """(line number, phrase) of every history phrase in ``text``."""
    return [(text.count("\n", 0, m.start()) + 1, m.group(0)) for m in HISTORY.finditer(text)]


def long_functions(source: str) -> list[tuple[str, int]]:
    """(qualified name, lines) of every function in ``source`` longer than ``MAX_FUNCTION_LINES``
    (its whole definition, decorators excluded, docstring included)."""
    out = []

    def visit(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    n = child.end_lineno - child.lineno + 1
                    if n > MAX_FUNCTION_LINES:
                        out.append((name, n))
                visit(child, name + ".")

    visit(ast.parse(source), "")
    return out


def _exceptions() -> dict[str, str]:
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())
    return data.get("tool", {}).get("wrinkles", {}).get("long-functions", {})


# --- the checks themselves are tested: they must catch what they exist to catch --------------


@pytest.mark.parametrize("text", [
    "the margin (was 50 mm) keeps", "10 mm until session 9", "measured in session 40",
    "see issue 3", "the old default of 12", "previously the solver", "since session 41 the cap",
    "The cap was 0.5 until the hips"])
def test_history_phrases_are_recognised(text):
    assert history_phrases(text), text


@pytest.mark.parametrize("text", [
    "train until interrupted", "doubling the radius until an anchor lies inside",
    "H100, 5k t-shirt: 3.76 against 3.95 ms per frame (docs/BENCHMARKS.md)",
    "the session's seed", "a wasted step", "far past +-5 the bodies are no longer human"])
def test_present_tense_text_is_not_history(text):
    assert not history_phrases(text), text


def test_long_functions_are_measured_with_their_docstrings():
    body = "\n".join(f"    x = {i}" for i in range(MAX_FUNCTION_LINES - 2))
    short = f'def f():\n    """doc"""\n{body}\n'
    assert long_functions(short) == []
    assert long_functions(short + "    return x\n") == [("f", MAX_FUNCTION_LINES + 1)]
    nested = "class A:\n" + "\n".join("    " + line for line in (short + "    return x\n").splitlines())
    assert long_functions(nested) == [("A.f", MAX_FUNCTION_LINES + 1)]


# --- the tree ----------------------------------------------------------------------------------


def test_no_history_in_the_product():
    found = []
    for p in _wording_files():
        text = p.read_text(errors="replace")
        found += [f"{_rel(p)}:{line}: {phrase!r}" for line, phrase in history_phrases(text)]
    assert not found, ("history belongs in git, CHANGELOG.md and docs/DECISIONS.md, not in the "
                       "product:\n" + "\n".join(found))


def test_no_history_in_file_names():
    bad = [_rel(p) for p in _tracked_files(WORDING_DIRS + CODE_DIRS) if HISTORY_NAME.search(p.name)]
    assert not bad, "file names that carry the history of a run:\n" + "\n".join(sorted(set(bad)))


def test_files_and_functions_within_their_limits():
    exceptions = _exceptions()
    problems = []
    for p in _tracked_files(CODE_DIRS):
        if p.suffix != ".py":
            continue
        source = p.read_text()
        lines = len(source.splitlines())
        if lines > MAX_FILE_LINES:
            problems.append(f"{_rel(p)}: {lines} lines (max {MAX_FILE_LINES})")
        for name, n in long_functions(source):
            if f"{_rel(p)}:{name}" not in exceptions:
                problems.append(f"{_rel(p)}:{name}: {n} lines (max {MAX_FUNCTION_LINES})")
    assert not problems, ("split these, or list a justified exception in pyproject.toml "
                          "[tool.wrinkles.long-functions]:\n" + "\n".join(problems))


def test_listed_exceptions_exist_and_give_a_reason():
    stale = []
    for key, reason in _exceptions().items():
        path, _, name = key.partition(":")
        source = (ROOT / path).read_text() if (ROOT / path).is_file() else ""
        if not source or name not in dict(long_functions(source)):
            stale.append(f"{key}: no such function over {MAX_FUNCTION_LINES} lines")
        if len(str(reason).split()) < 5:
            stale.append(f"{key}: the reason is missing or too short")
    assert not stale, "\n".join(stale)


def test_tests_do_not_import_benchmarks():
    bad = []
    for p in _tracked_files(("tests",)):
        if p.suffix != ".py":
            continue
        for node in ast.walk(ast.parse(p.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            bad += [f"{_rel(p)}:{node.lineno}: {n}" for n in names if n.split(".")[0] == "benchmarks"]
    assert not bad, "tests import benchmarks:\n" + "\n".join(bad)


def test_numeric_asserts_say_what_differs():
    bare = re.compile(r"^\s*assert\s+(?:not\s+)?(?:np|numpy)\.(?:allclose|array_equal)\(", re.MULTILINE)
    bad = [f"{_rel(p)}:{p.read_text().count(chr(10), 0, m.start()) + 1}"
           for p in _tracked_files(("tests",)) if p.suffix == ".py"
           for m in bare.finditer(p.read_text())]
    assert not bad, "use np.testing.assert_allclose / assert_array_equal:\n" + "\n".join(bad)


@pytest.mark.parametrize("doc", sorted(DOC_BUDGETS))
def test_maps_stay_short(doc):
    lines = len((ROOT / doc).read_text().splitlines())
    assert lines <= DOC_BUDGETS[doc], f"{doc}: {lines} lines (budget {DOC_BUDGETS[doc]})"


def test_the_declared_licence_ships():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "Apache-2.0" and project["license-files"] == ["LICENSE"]
    text = (ROOT / "LICENSE").read_text()
    assert "Apache License" in text and "Version 2.0, January 2004" in text
