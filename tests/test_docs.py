"""The documentation as tests: every page's code runs, top to bottom, in a fresh folder.

One test per page (``README.md`` and ``docs/guide/*.md``). A page's fenced blocks run in their
order, as a reader pasting them would: ``python`` blocks in one namespace (one interpreter per
page), ``bash``/``sh``/``shell`` blocks as bash scripts (``set -e -o pipefail``) in which
``python`` and ``ao4d`` are this interpreter; other blocks (output, ``toml``, ``{toctree}``) are
not run. The page starts in an empty folder: what a block needs, an earlier block of the page
makes, or ``ao4d.data``'s sample data (cached in the session's ``AO4D_DATA_DIR``, see conftest).

What a block needs beyond that is said in HTML comments right above its fence, invisible on
GitHub and in the Sphinx site, visible in the source:

``<!-- docs-test: skip REASON -->``
    the block does not run (installs, minutes of machine time); the reason is required.
``<!-- docs-test: replace "OLD" "NEW" -->``
    the test runs the block with OLD replaced by NEW (smaller sizes); OLD must occur in it.
``<!-- docs-test: skip-lines "TEXT" REASON -->``
    the lines of a bash block that contain TEXT do not run (a server that runs until Ctrl-C).
``<!-- docs-test: file NAME -->``
    the block is a file the reader saves (a config): the test writes it to NAME.

A block fails when it raises or exits non-zero, and when its output shows a warning of ao4d's
or datasets_gen's own (the docs' examples are meant to run clean); the message names the page,
the block's line and its output. Run as a script (``python tests/test_docs.py SPEC.json``) this
file is the per-page driver the tests start.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs" / "guide").glob("*.md"))]

RUN_LANGUAGES = {"python": "python", "bash": "bash", "sh": "bash", "shell": "bash"}
MARKER = re.compile(r"^\s*<!--\s*docs-test:\s*(?P<body>.*?)\s*-->\s*$")
QUOTED = re.compile(r'"([^"]*)"')  # a marker's quoted text (no quotes inside)
FENCE = re.compile(r"^(?P<indent>\s*)(?P<fence>`{3,}|~{3,})\s*(?P<info>[^`]*)$")
PAGE_TIMEOUT_S = 400
# warnings the examples may show: no OpenCL device on this machine (the numpy backend runs)
ALLOWED_WARNINGS = {"NoOpenCLDeviceWarning"}


@dataclass
class Block:
    line: int  # 1-based line of the opening fence
    language: str
    code: str
    kind: str = ""  # "python", "bash", "file", or "" (not run)
    skip: str = ""  # the reason, for a block that does not run
    file: str = ""
    replacements: list[tuple[str, str]] = field(default_factory=list)
    skipped_lines: list[str] = field(default_factory=list)  # "line: reason"


def parse(path: Path) -> list[Block]:
    """The fenced blocks of a Markdown page with their ``docs-test`` markers applied."""
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks: list[Block] = []
    pending: list[tuple[int, str]] = []  # markers waiting for their block
    i = 0
    while i < len(lines):
        marker = MARKER.match(lines[i])
        fence = FENCE.match(lines[i])
        if marker:
            pending.append((i + 1, marker["body"]))
            i += 1
            continue
        if not fence:
            if lines[i].strip() and pending:
                raise ValueError(f"{path.name}:{pending[0][0]}: a docs-test marker must stand right above a fence")
            i += 1
            continue
        start, close, indent = i, fence["fence"], len(fence["indent"])
        i += 1
        body = []
        while i < len(lines) and not (lines[i].strip().startswith(close) and not lines[i].strip().strip(close[0])):
            body.append(lines[i][indent:] if lines[i][:indent].strip() == "" else lines[i])
            i += 1
        i += 1  # the closing fence
        info = fence["info"].strip()
        language = info.split()[0].lower() if info else ""
        block = Block(
            line=start + 1, language=language, code="\n".join(body) + "\n", kind=RUN_LANGUAGES.get(language, "")
        )
        for where, text in pending:
            _apply(block, text, f"{path.name}:{where}")
        pending = []
        if block.kind in ("python", "bash") and not block.skip and "pip install" in block.code:
            raise ValueError(f"{path.name}:{block.line}: a block that installs packages needs a docs-test skip marker")
        blocks.append(block)
    if pending:
        raise ValueError(f"{path.name}:{pending[0][0]}: a docs-test marker with no block below it")
    return blocks


def _apply(block: Block, text: str, where: str) -> None:
    verb, _, rest = text.partition(" ")
    rest = rest.strip()
    if verb == "skip":
        if not rest:
            raise ValueError(f"{where}: docs-test skip needs a reason")
        block.skip = rest
    elif verb == "replace":
        parts = QUOTED.findall(rest)
        if len(parts) != 2 or QUOTED.sub("", rest).strip():
            raise ValueError(f'{where}: docs-test replace takes "OLD" "NEW", got {rest!r}')
        if parts[0] not in block.code:
            raise ValueError(f"{where}: docs-test replace: {parts[0]!r} is not in the block below")
        block.code = block.code.replace(parts[0], parts[1])
        block.replacements.append((parts[0], parts[1]))
    elif verb == "skip-lines":
        quoted = QUOTED.match(rest)
        reason = rest[quoted.end() :].strip() if quoted else ""
        if not reason or block.kind != "bash":
            raise ValueError(f'{where}: docs-test skip-lines takes "TEXT" REASON, above a bash block')
        text = quoted[1]
        lines = block.code.splitlines()
        hits = [n for n, line in enumerate(lines) if text in line]
        if not hits or any(lines[n].rstrip().endswith("\\") for n in hits):
            raise ValueError(f"{where}: docs-test skip-lines: no whole line of the block below has {text!r}")
        for n in hits:
            block.skipped_lines.append(f"{lines[n].strip()}: {reason}")
            lines[n] = ": skipped by docs-test"
        block.code = "\n".join(lines) + "\n"
    elif verb == "file":
        if not rest or "/" in rest:
            raise ValueError(f"{where}: docs-test file needs a file name")
        block.kind, block.file = "file", rest
    else:
        raise ValueError(f"{where}: unknown docs-test marker {text!r} (skip, skip-lines, replace, file)")


def _own_warnings() -> set[str]:
    """Names of the warning classes ao4d and datasets_gen define."""
    names = set()
    for package in ("ao4d", "datasets_gen"):
        for source in (ROOT / package).rglob("*.py"):
            names.update(re.findall(r"^class (\w+Warning)\(", source.read_text(encoding="utf-8"), re.M))
    return names - ALLOWED_WARNINGS


# ---------------------------------------------------------------------------------------- tests

try:
    import pytest
except ImportError:  # the driver below runs without pytest
    pytest = None

if pytest is not None:

    @pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
    def test_page_runs(page, tmp_path):
        blocks = parse(page)
        name = str(page.relative_to(ROOT))
        if not any(b.kind in ("python", "bash", "file") and not b.skip for b in blocks):
            pytest.skip(f"{name}: no block to run")
        shims = tmp_path / "bin"
        shims.mkdir()
        for command, target in (("python", ""), ("ao4d", " -m ao4d")):
            (shims / command).write_text(f'#!/bin/sh\nexec {shlex.quote(sys.executable)}{target} "$@"\n')
            (shims / command).chmod(0o755)
        work = tmp_path / "work"
        work.mkdir()
        spec = tmp_path / "blocks.json"
        spec.write_text(json.dumps({"page": name, "blocks": [asdict(b) for b in blocks]}))
        env = dict(os.environ, PATH=f"{shims}{os.pathsep}{os.environ.get('PATH', '')}", MPLBACKEND="Agg")
        try:
            run = subprocess.run(
                [sys.executable, "-u", str(Path(__file__).resolve()), str(spec)],
                cwd=work,
                env=env,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                timeout=PAGE_TIMEOUT_S,
            )
        except subprocess.TimeoutExpired as exc:
            out = exc.stdout if isinstance(exc.stdout, str) else (exc.stdout or b"").decode(errors="replace")
            pytest.fail(f"{name}: timed out after {PAGE_TIMEOUT_S} s\n{out[-6000:]}", pytrace=False)
        if run.returncode != 0:
            failed = re.findall(r"^DOCS-TEST FAILED (.*)$", run.stdout, re.M)
            pytest.fail(f"{name}: {failed[-1] if failed else 'the driver failed'}\n{run.stdout[-8000:]}", pytrace=False)
        print(run.stdout)  # each block's output and time: pytest -rP shows it
        warned = sorted(set(re.findall(r"\b(\w+Warning)\b", run.stdout)) & _own_warnings())
        assert not warned, f"{name}: the examples warn ({', '.join(warned)})\n{run.stdout[-8000:]}"

    def test_markers_are_checked(tmp_path):
        page = tmp_path / "page.md"
        good = (
            '<!-- docs-test: replace "48" "16" -->\n```python\nx = 48\n```\n\n```toml\na = 1\n```\n'
            '<!-- docs-test: skip-lines "--serve" it\'s a server -->\n```bash\nao4d view a.npz\nao4d view b.npz --serve\n```\n'
        )
        page.write_text(good)
        blocks = parse(page)
        assert [b.kind for b in blocks] == ["python", "", "bash"] and blocks[0].code == "x = 16\n"
        assert blocks[2].code.splitlines()[0] == "ao4d view a.npz" and "--serve" not in blocks[2].code
        assert blocks[2].skipped_lines == ["ao4d view b.npz --serve: it's a server"]
        for bad, says in [
            ("<!-- docs-test: skip -->\n```bash\nls\n```\n", "needs a reason"),
            ('<!-- docs-test: replace "99" "1" -->\n```python\nx = 48\n```\n', "is not in the block"),
            ("<!-- docs-test: frobnicate -->\n```python\nx = 1\n```\n", "unknown docs-test marker"),
            ("<!-- docs-test: skip why -->\ntext\n```python\nx = 1\n```\n", "right above a fence"),
            ("```bash\npip install ao4d\n```\n", "needs a docs-test skip marker"),
            ('<!-- docs-test: skip-lines "nowhere" why -->\n```bash\nls\n```\n', "no whole line"),
            ('<!-- docs-test: skip-lines "ls" -->\n```bash\nls\n```\n', "takes"),
        ]:
            page.write_text(bad)
            with pytest.raises(ValueError, match=says):
                parse(page)


# ---------------------------------------------------------------------------------------- driver


def _drive(spec_path: str) -> int:
    """Run one page's blocks in the current folder; print each block's output and time."""
    import traceback

    spec = json.loads(Path(spec_path).read_text())
    page = spec["page"]
    namespace: dict = {"__name__": "__main__"}
    for block in spec["blocks"]:
        where = f"{page}:{block['line']}"
        if not block["kind"]:
            continue
        if block["skip"]:
            print(f"=== {where} ({block['language']}): skipped: {block['skip']}", flush=True)
            continue
        print(f"=== {where} ({block['kind'] if block['kind'] != 'file' else 'file ' + block['file']})", flush=True)
        for line in block["skipped_lines"]:
            print(f"    skipped: {line}", flush=True)
        start = time.perf_counter()
        if block["kind"] == "file":
            Path(block["file"]).write_text(block["code"], encoding="utf-8")
            continue
        if block["kind"] == "python":
            # line numbers in tracebacks are the page's: the code starts on the line after the fence
            code = "\n" * block["line"] + block["code"]
            try:
                exec(compile(code, page, "exec"), namespace)
            except BaseException:
                traceback.print_exc()
                print(f"DOCS-TEST FAILED {where} (python block)", flush=True)
                return 1
            sys.stdout.flush()
            sys.stderr.flush()
        else:
            status = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", block["code"]], stdin=subprocess.DEVNULL)
            if status.returncode != 0:
                print(f"DOCS-TEST FAILED {where} (bash block, exit status {status.returncode})", flush=True)
                return 1
        print(f"--- {where}: {time.perf_counter() - start:.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.stderr = sys.stdout  # one stream, in order, for the test's message
    sys.exit(_drive(sys.argv[1]))
