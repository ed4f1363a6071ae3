"""The house rules that tools can check: modules depend one way (no import cycles, in Rust or
Python, and docs/architecture.md drawn from today's sources), and no function of the Rust
orchestrator is longer than 80 lines."""

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LONGEST_FUNCTION = 80


def test_no_module_imports_another_in_a_circle_and_the_picture_is_current():
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "module-graph.py"), "--check"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr


def rust_functions(text: str) -> list[tuple[str, int, int]]:
    """(name, first line, lines) of every `fn` with a body in Rust source `text`."""
    # Blank out comments and string literals, keeping line breaks, so braces in them don't count.
    def blank(match: re.Match) -> str:
        return re.sub(r"[^\n]", " ", match.group(0))
    code = re.sub(r'//[^\n]*|/\*.*?\*/|r#*"(?:.|\n)*?"#*|"(?:\\.|[^"\\])*"|\'(?:\\.|[^\'\\])\'', blank, text, flags=re.S)
    found = []
    for match in re.finditer(r"\bfn\s+(\w+)[^;{]*\{", code):
        depth, end = 0, match.end() - 1
        for end in range(match.end() - 1, len(code)):
            depth += {"{": 1, "}": -1}.get(code[end], 0)
            if depth == 0:
                break
        first = code.count("\n", 0, match.start()) + 1
        found.append((match.group(1), first, code.count("\n", match.start(), end) + 1))
    return found


def test_the_function_finder_measures_what_it_should():
    text = 'fn a() {\n    let s = "}}}";\n    // }\n}\nfn b(x: u8) -> u8 { x }\n'
    assert rust_functions(text) == [("a", 1, 4), ("b", 5, 1)]


def test_no_function_of_the_orchestrator_is_over_80_lines():
    long = [f"{path.relative_to(ROOT)}:{line} {name} ({lines} lines)"
            for path in sorted((ROOT / "orchestrator" / "src").rglob("*.rs"))
            if "tests" not in path.stem
            for name, line, lines in rust_functions(path.read_text())
            if lines > LONGEST_FUNCTION]
    assert not long, "functions over 80 lines:\n" + "\n".join(long)
