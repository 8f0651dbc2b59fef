"""The mutation harness: would the tests notice a plausible bug in the numerics?

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.mutation            # every mutant, area tests
    python -m benchmarks.mutation --list                            # names, files, reasons
    python -m benchmarks.mutation --only ssn_armijo_sign bathe_gamma
    python -m benchmarks.mutation --full                            # the README's command

Each mutant in `benchmarks/mutants.py` is one edit of one line of `nivpjax/`: a sign, a
coefficient, a dropped term, a swapped bound, a changed default, each at a line whose comment
or docstring says why the line is what it is. The harness copies the repository (the package,
the tests and what they import) into a scratch directory per mutant, applies the edit there
(never in the working tree), and runs `python -m pytest -x -p no:xdist <the mutant's tests>`
with the scratch directory first on `PYTHONPATH`, so the scratch package shadows the
installed one (checked: the scratch copy's `nivpjax.__file__` is printed and asserted). With
`--full` it runs the README's command, `python -m pytest -n 2 tests -x`, instead.

A mutant is *killed* when pytest fails (exit status 1; 2, an interrupted or uncollectable
run, e.g. a mutant that does not import, counts as killed and is flagged `error`), *survived*
when it passes, and *timeout* (killed, flagged) when it runs past `--timeout`. Before the
mutants, the unmutated copy runs each area's tests once (the union of its mutants'
selections): a mutant whose area fails unmutated is not run (`baseline failed`).

Why a curated list and not mutmut or cosmic-ray: both generate every operator mutant of every
line (thousands here) and run the suite on each. The suite compiles a JAX program per test,
so one run is minutes (about 18 on 2 cores for the whole suite, 0.5-3 for one area's files),
and thousands of them are days. Most generated mutants sit on input checks, messages and
plumbing whose failures are loud anyway, or are equivalent (a `<` against `<=` on a float that
never ties); neither tool knows which lines carry the numerics' claims. The curated list
targets exactly those lines, each with the claim it tests, and runs in about an hour
(93 mutants: 60 min on 2 cores shared with other work, 22 of them the baselines).

Writes `benchmarks/results/mutation.{md,csv}` (`--out` to change the stem).
"""

import argparse
import csv
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from .mutants import EQUIVALENT, MUTANTS, Mutant


ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
# What the tests import or read: the package, the tests and their helpers, the examples
# (test_examples, the references), the benchmarks (test_reliability), the docs
# (test_docs runs the pages' snippets) and the project files.
COPY = (
    "nivpjax",
    "tests",
    "examples",
    "benchmarks",
    "docs",
    "pyproject.toml",
    "README.md",
    "mkdocs.yml",
)
IGNORE = shutil.ignore_patterns("__pycache__", "*.pyc", ".pytest_cache", "output", "site")
FULL_COMMAND = ("-n", "2", "tests", "-x")


class MutantError(ValueError):
    """A mutant whose original text does not occur exactly once in its file."""


def check(mutant: Mutant, root: Path = ROOT) -> str:
    """The mutated text of the mutant's file; raises `MutantError` unless the original text
    occurs exactly once and differs from the replacement."""
    path = root / mutant.file
    if not path.is_file():
        raise MutantError(f"{mutant.name}: no file {mutant.file}")
    text = path.read_text()
    count = text.count(mutant.original)
    if count != 1:
        raise MutantError(
            f"{mutant.name}: the original text occurs {count} times in {mutant.file} "
            f"(must be exactly once): {mutant.original!r}"
        )
    if mutant.original == mutant.replacement:
        raise MutantError(f"{mutant.name}: the replacement equals the original")
    return text.replace(mutant.original, mutant.replacement)


def scratch_copy(dest: Path, root: Path = ROOT) -> None:
    for name in COPY:
        src = root / name
        if src.is_dir():
            shutil.copytree(src, dest / name, ignore=IGNORE)
        elif src.is_file():
            shutil.copy2(src, dest / name)


def _env(scratch: Path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(scratch) + os.pathsep + env.get("PYTHONPATH", "")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


def imported_from(scratch: Path) -> str:
    """Where `nivpjax` is imported from with the scratch copy on the path."""
    out = subprocess.run(
        [sys.executable, "-c", "import nivpjax; print(nivpjax.__file__)"],
        cwd=scratch,
        env=_env(scratch),
        capture_output=True,
        text=True,
        check=True,
    )
    return out.stdout.strip()


def run_tests(scratch: Path, tests, full: bool, timeout: float):
    """(exit status or None on timeout, seconds, last lines of output)."""
    args = FULL_COMMAND if full else ("-x", "-p", "no:xdist", *tests)
    cmd = [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", *args]
    t = time.perf_counter()
    try:
        out = subprocess.run(
            cmd, cwd=scratch, env=_env(scratch), capture_output=True, text=True, timeout=timeout
        )
    except subprocess.TimeoutExpired:
        return None, time.perf_counter() - t, "timeout"
    tail = (out.stdout + out.stderr).strip().splitlines()[-3:]
    return out.returncode, time.perf_counter() - t, " | ".join(tail)


def outcome(rc) -> str:
    if rc is None:
        return "killed (timeout)"
    if rc == 0:
        return "survived"
    if rc == 1:
        return "killed"
    if rc == 2:
        return "killed (error)"
    return f"harness error (pytest exit {rc})"


def run_mutant(mutant: Mutant, full: bool, timeout: float, log, snapshot: Path) -> dict:
    mutated = check(mutant, snapshot)
    with tempfile.TemporaryDirectory(prefix="nivpjax-mutant-") as tmp:
        scratch = Path(tmp)
        scratch_copy(scratch, snapshot)
        (scratch / mutant.file).write_text(mutated)
        rc, seconds, tail = run_tests(scratch, mutant.tests, full, timeout)
    row = dict(
        name=mutant.name,
        module=mutant.file,
        reason=mutant.reason,
        tests=" ".join(mutant.tests) if not full else "full suite",
        outcome=outcome(rc),
        seconds=round(seconds, 1),
        run=_today(),
        tail=tail,
    )
    log(f"{mutant.name:<32} {row['outcome']:<18} {seconds:7.1f} s  {tail[-160:]}")
    return row


def baselines(mutants, full: bool, timeout: float, log, snapshot: Path) -> dict:
    """area -> (passed, seconds, tail) for the unmutated copy."""
    areas = {}
    for m in mutants:
        areas.setdefault(m.area, [])
        areas[m.area] += [t for t in m.tests if t not in areas[m.area]]
    if full:
        areas = {"full suite": []}
    out = {}
    with tempfile.TemporaryDirectory(prefix="nivpjax-baseline-") as tmp:
        scratch = Path(tmp)
        scratch_copy(scratch, snapshot)
        where = imported_from(scratch)
        if not where.startswith(str(scratch)):
            raise SystemExit(f"the scratch copy does not shadow the installed package: {where}")
        log(f"nivpjax imported from {where}")
        for area, tests in areas.items():
            rc, seconds, tail = run_tests(scratch, tests, full, timeout)
            out[area] = (rc == 0, seconds, tail)
            log(
                f"baseline {area:<24} {'passed' if rc == 0 else 'FAILED'} {seconds:7.1f} s  "
                f"{tail[-160:]}"
            )
    return out


def _today() -> str:
    return time.strftime("%Y-%m-%d", time.gmtime())


FIELDS = ["name", "module", "reason", "tests", "outcome", "seconds", "run"]
BASELINE = "(baseline) "


def merge(rows, base, stem: Path):
    """The rows and baselines of the table at `stem`, with those of this run replacing
    theirs (a rerun of some mutants after a test was added)."""
    path = stem.with_suffix(".csv")
    if not path.is_file():
        return rows, base
    with open(path, newline="") as f:
        old = list(csv.DictReader(f))
    new = {r["name"]: r for r in rows}
    base = dict(base)
    for r in old:
        if r["name"].startswith(BASELINE):
            area = r["name"].removeprefix(BASELINE)
            base.setdefault(area, (r["outcome"] == "passed", float(r["seconds"]), ""))
    current = {m.name: m for m in MUTANTS}  # mutants since removed from the list drop out
    merged = [
        new.pop(r["name"], r)
        for r in old
        if not r["name"].startswith(BASELINE) and r["name"] in current
    ]
    for r in merged:  # the reasons as the list now states them (e.g. "equivalent: ...")
        r["reason"] = current[r["name"]].reason
        r.setdefault("run", "")
    return merged + list(new.values()), base


def write(rows, stem: Path, full: bool, base) -> None:
    stem.parent.mkdir(parents=True, exist_ok=True)
    with open(stem.with_suffix(".csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=FIELDS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
        w.writerows(
            dict(
                name=BASELINE + area,
                module="",
                reason="the unmutated copy",
                tests="",
                outcome="passed" if ok else "FAILED",
                seconds=round(s, 1),
                run="",
            )
            for area, (ok, s, _) in base.items()
        )
    judged = [r for r in rows if r["outcome"].startswith(("killed", "survived"))]
    killed = [r for r in judged if r["outcome"].startswith("killed")]
    survived = [r for r in judged if r["outcome"] == "survived"]
    score = f"{len(killed)} of {len(judged)} killed" + (
        f" ({100 * len(killed) / len(judged):.0f}%)" if judged else ""
    )
    lines = [
        "# Mutation score",
        "",
        "Written by `python -m benchmarks.mutation` "
        f"({'the README test command, whole suite' if full else 'each mutant: its area tests, -x'}"
        f"; {time.strftime('%Y-%m-%d', time.gmtime())}). Mutants and their reasons: "
        "`benchmarks/mutants.py`; how to run it: `docs/development/mutation.md`.",
        "",
        f"**Score: {score}.**"
        + (" Survived: " + ", ".join(f"`{r['name']}`" for r in survived) + "." if survived else ""),
        "",
        "Equivalent mutants, proven so and excluded from the list and the score: "
        + ", ".join(f"`{n}`" for n in EQUIVALENT)
        + " (reasons in `benchmarks/mutants.py`, `EQUIVALENT`). Column *run*: the date of "
        "each row's latest run (`--only` reruns replace their rows and keep the others').",
        "",
        "Baselines (the unmutated copy, each area's tests): "
        + ", ".join(
            f"{a} {'passed' if ok else 'FAILED'} ({s:.0f} s)" for a, (ok, s, _) in base.items()
        )
        + ".",
        "",
        "| mutant | module | reason | tests run | outcome | s | run |",
        "|---|---|---|---|---|---:|---|",
    ]
    for r in rows:
        tests = "<br>".join(f"`{t}`" for t in r["tests"].split()) if not full else "suite"
        reason = r["reason"].replace("|", "\\|")
        lines.append(
            f"| `{r['name']}` | `{r['module'].removeprefix('nivpjax/')}` | {reason} | "
            f"{tests} | {r['outcome']} | {r['seconds']} | {r.get('run') or ''} |"
        )
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    if stem == RESULTS / "mutation" and DOCS_PAGE.is_file():
        _update_docs(score, survived, full)


DOCS_PAGE = ROOT / "docs" / "development" / "mutation.md"
MARK, END = "<!-- mutation-score -->", "<!-- /mutation-score -->"


def _update_docs(score, survived, full) -> None:
    """The score line of the docs page, between its markers."""
    text = DOCS_PAGE.read_text()
    if MARK not in text or END not in text:
        return
    names = ", ".join(f"`{r['name']}`" for r in survived) or "none"
    block = (
        f"{MARK}\n**{score}** ({'the whole suite' if full else 'area tests'}, "
        f"{time.strftime('%Y-%m-%d', time.gmtime())}). Survivors: {names}.\n{END}"
    )
    head, rest = text.split(MARK, 1)
    DOCS_PAGE.write_text(head + block + rest.split(END, 1)[1])


def main(argv=None):
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.mutation", description=__doc__.split("\n")[0]
    )
    p.add_argument("--only", nargs="+", metavar="NAME", help="run these mutants only")
    p.add_argument("--list", action="store_true", help="list the mutants and exit")
    p.add_argument("--jobs", type=int, default=1, help="mutants run in parallel (default 1)")
    p.add_argument(
        "--full",
        action="store_true",
        help="run the README's command (python -m pytest -n 2 tests -x) per mutant",
    )
    p.add_argument("--timeout", type=float, default=900.0, help="seconds per pytest run")
    p.add_argument("--no-baseline", action="store_true", help="skip the unmutated runs")
    p.add_argument(
        "--out",
        type=Path,
        default=RESULTS / "mutation",
        help="output stem (.md and .csv are written)",
    )
    a = p.parse_args(argv)

    names = [m.name for m in MUTANTS]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise SystemExit(f"duplicate mutant names: {sorted(dup)}")
    mutants = MUTANTS
    if a.only:
        unknown = sorted(set(a.only) - set(names))
        if unknown:
            raise SystemExit(f"unknown mutants {unknown}; --list names them")
        mutants = [m for m in MUTANTS if m.name in a.only]
    errors = []
    for m in mutants:
        try:
            check(m)
        except MutantError as e:
            errors.append(str(e))
    if errors:
        raise SystemExit("bad mutants:\n  " + "\n  ".join(errors))
    if a.list:
        for m in mutants:
            print(f"{m.name:<32} {m.area:<12} {m.file}: {m.reason}")
        print(f"{len(mutants)} mutants")
        return

    def log(msg):
        print(msg, flush=True)

    t = time.perf_counter()
    # One snapshot of the tree when the run starts: edits made while it runs (a new test
    # for a survivor) do not leak into later mutants' copies.
    snapshot_dir = tempfile.TemporaryDirectory(prefix="nivpjax-snapshot-")
    snapshot = Path(snapshot_dir.name)
    scratch_copy(snapshot)
    base = {} if a.no_baseline else baselines(mutants, a.full, a.timeout, log, snapshot)
    area_ok = {area: ok for area, (ok, _, _) in base.items()}

    def one(m):
        if base and not area_ok.get("full suite" if a.full else m.area, False):
            return dict(
                name=m.name,
                module=m.file,
                reason=m.reason,
                tests=" ".join(m.tests),
                outcome="baseline failed",
                seconds=0.0,
                run=_today(),
            )
        row = run_mutant(m, a.full, a.timeout, log, snapshot)
        with lock:  # the table so far, so that an interrupted run leaves its results
            done[m.name] = row
            partial = [done[n.name] for n in mutants if n.name in done]
            if not a.only:
                write(partial, a.out, a.full, base)
        return row

    done, lock = {}, threading.Lock()
    with ThreadPoolExecutor(max_workers=max(1, a.jobs)) as pool:
        rows = list(pool.map(one, mutants))
    snapshot_dir.cleanup()
    if a.only:  # merge into the last full table: rerun mutants replace their rows
        rows, base = merge(rows, base, a.out)
    write(rows, a.out, a.full, base)
    killed = sum(r["outcome"].startswith("killed") for r in rows)
    log(
        f"{killed} of {len(rows)} killed in {time.perf_counter() - t:.0f} s; "
        f"wrote {a.out.with_suffix('.md')}"
    )


if __name__ == "__main__":
    main()
