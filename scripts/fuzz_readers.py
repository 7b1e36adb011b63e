"""Fuzz microcal's file readers with many generated inputs and summarise what each did.

    python scripts/fuzz_readers.py [--count N] [--seed S] [--reader NAME] [--shrink]

Runs the generators of ``tests/formats/test_fuzz_readers.py`` (valid files of each kind,
mutated) for ``N`` inputs per reader, in this process, and prints per reader: inputs tried,
how many were read, refused with a MicrocalError, raised another exception (grouped by type
and the line of microcal that raised it, with the first few inputs) or hung (no answer
within 5 s), and the time taken. MicrocalError messages that do not name the file or span
several lines are counted too (a note, not a failure). ``--shrink`` then lets Hypothesis
reduce each distinct failure to a minimal input.

Exit code 0 when every input was read or refused with a MicrocalError, 1 when any raised
another exception or hung.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import traceback
import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import hypothesis
from hypothesis import HealthCheck, Phase, given, settings

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "formats"))

from test_fuzz_readers import (  # the generators live with their tests
    HANG_SECONDS,
    READERS,
    FuzzCase,
    Outcome,
    Reader,
    run_case,
    seed_files,
)

#: Inputs shown per distinct failure.
SHOWN = 3
#: An input read slower than this, s, is shown (not a failure: hangs are HANG_SECONDS).
SLOW_SECONDS = 0.5
SRC = Path(__file__).resolve().parents[1] / "src"


def origin(exc: BaseException) -> str:
    """Where an exception was raised: the innermost line of microcal (``formats/x.py:12``),
    followed by the innermost line overall when that is elsewhere (``json/decoder.py:353``)."""
    frames = traceback.extract_tb(exc.__traceback__)
    ours = [f for f in frames if Path(f.filename).resolve().is_relative_to(SRC)]
    where = []
    if ours:
        f = ours[-1]
        where.append(f"{Path(f.filename).resolve().relative_to(SRC)}:{f.lineno} ({f.name})")
    if frames and (not ours or frames[-1] is not ours[-1]):
        f = frames[-1]
        where.append(f"in {Path(f.filename).name}:{f.lineno} ({f.name})")
    return " ".join(where) or "?"


def _where(filename: str, lineno: int) -> str:
    path = Path(filename).resolve()
    return f"{path.relative_to(SRC) if path.is_relative_to(SRC) else path.name}:{lineno}"


def type_name(exc: BaseException | None) -> str:
    """``ValueError``, ``csv.Error``: the exception's class, with its module unless built in."""
    cls = type(exc)
    module = cls.__module__.removeprefix("_")
    return cls.__qualname__ if module == "builtins" else f"{module}.{cls.__qualname__}"


@dataclass
class Failure:
    """Inputs that raised one kind of exception at one place."""

    count: int = 0
    examples: list[tuple[str, FuzzCase]] = field(default_factory=list)


@dataclass
class Summary:
    """What one reader did with its inputs."""

    reader: Reader
    counts: Counter[str] = field(default_factory=Counter)
    failures: dict[tuple[str, str], Failure] = field(default_factory=dict)
    odd_messages: list[tuple[str, FuzzCase]] = field(default_factory=list)
    n_odd_messages: int = 0
    slowest: float = 0.0
    slowest_case: FuzzCase | None = None
    seconds: float = 0.0
    warnings: Counter[tuple[str, str, str]] = field(default_factory=Counter)

    def add(self, case: FuzzCase, outcome: Outcome, path: Path) -> None:
        """Count one input and keep the first few of each failure."""
        self.counts[outcome.kind] += 1
        if outcome.seconds >= self.slowest:
            self.slowest, self.slowest_case = outcome.seconds, case
        error = outcome.error
        if outcome.kind in ("other", "hang"):
            name = "hang" if outcome.kind == "hang" else type_name(error)
            where = origin(error) if error is not None else "(measured after it returned)"
            failure = self.failures.setdefault((name, where), Failure())
            failure.count += 1
            if len(failure.examples) < SHOWN:
                message = str(error) if error is not None else f"{outcome.seconds:.1f} s"
                failure.examples.append((message, case))
        elif outcome.kind == "refused":
            message = str(error)
            if str(path) not in message or "\n" in message:
                self.n_odd_messages += 1
                if len(self.odd_messages) < SHOWN:
                    self.odd_messages.append((message, case))

    @property
    def failed(self) -> bool:
        """An input raised something other than MicrocalError, or hung."""
        return bool(self.failures)

    def print(self) -> None:
        """The reader's lines of the report."""
        c = self.counts
        print(
            f"{self.reader.name:<13} tried {sum(c.values()):>6}  returned {c['returned']:>6}  "
            f"MicrocalError {c['refused']:>6}  other {c['other']:>5}  hangs {c['hang']:>3}  "
            f"time {self.seconds:7.1f} s (slowest input {self.slowest:.3f} s)"
        )
        if self.slowest_case is not None and self.slowest > SLOW_SECONDS:
            print(f"    slowest input: {self.slowest_case.short()}")
        for (name, where), failure in sorted(self.failures.items(), key=lambda kv: -kv[1].count):
            print(f"    {name} x{failure.count} at {where}")
            for message, case in failure.examples:
                print(f"        {_one_line(message, 200)}")
                print(f"            input: {case.short()}")
        if self.warnings:
            print(
                f"    note: {sum(self.warnings.values())} warning(s) while reading "
                f"({len(self.warnings)} distinct), e.g."
            )
            for (category, where, message), n in self.warnings.most_common(SHOWN):
                print(f"        {category} x{n} at {where}: {_one_line(message, 160)}")
        if self.n_odd_messages:
            print(
                f"    note: {self.n_odd_messages} MicrocalError message(s) do not name the file "
                f"or span several lines, e.g."
            )
            for message, case in self.odd_messages:
                print(f"        {_one_line(message, 200)}")
                print(f"            input: {case.short()}")


def _one_line(text: str, limit: int) -> str:
    text = repr(text)[1:-1] if "\n" in text else text
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _settings(count: int, phases: tuple[Phase, ...]) -> settings:
    return settings(
        max_examples=count,
        phases=phases,
        database=None,
        deadline=None,
        print_blob=False,
        derandomize=False,
        suppress_health_check=list(HealthCheck),
    )


def fuzz(reader: Reader, count: int, seed: int, directory: Path) -> Summary:
    """Run ``count`` generated inputs through one reader."""
    summary = Summary(reader)
    path = directory / reader.file_name

    @_settings(count, (Phase.generate,))
    @hypothesis.seed(seed)
    @given(case=reader.inputs)
    def run(case: FuzzCase) -> None:
        summary.add(case, run_case(reader, case, directory), path)

    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run()
    summary.seconds = time.perf_counter() - start
    summary.warnings.update(
        (w.category.__name__, _where(w.filename, w.lineno), str(w.message)) for w in caught
    )
    return summary


def shrink(reader: Reader, count: int, seed: int, directory: Path) -> list[str]:
    """Hypothesis's minimal input of each distinct failure of ``reader`` (its report)."""

    @_settings(count, (Phase.generate, Phase.shrink))
    @hypothesis.seed(seed)
    @given(case=reader.inputs)
    def run(case: FuzzCase) -> None:
        outcome = run_case(reader, case, directory)
        if outcome.kind == "hang":
            raise AssertionError(f"no answer within {HANG_SECONDS} s")
        if outcome.kind == "other" and outcome.error is not None:
            raise outcome.error

    try:
        run()
    except BaseException as exc:
        if isinstance(exc, KeyboardInterrupt):
            raise
        errors = list(exc.exceptions) if isinstance(exc, BaseExceptionGroup) else [exc]
        return [
            f"{type_name(e)}: {_one_line(str(e), 300)}\n      at {origin(e)}\n      "
            + "\n      ".join(getattr(e, "__notes__", []))
            for e in errors
        ]
    return []


def main(argv: list[str] | None = None) -> int:
    """Fuzz the readers named on the command line (all by default); 1 if any failed."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=10000, help="inputs per reader")
    parser.add_argument("--seed", type=int, default=0, help="seed of the generators")
    parser.add_argument("--reader", choices=sorted(READERS), help="fuzz this reader only")
    parser.add_argument(
        "--shrink", action="store_true", help="reduce each failure to a minimal input"
    )
    args = parser.parse_args(argv)
    if args.count < 1:
        parser.error("--count: expected at least 1")
    names = [args.reader] if args.reader else list(READERS)
    start = time.perf_counter()
    seed_files()
    print(f"valid files built in {time.perf_counter() - start:.1f} s; {args.count} inputs per "
          f"reader, seed {args.seed}")  # fmt: skip
    failed = False
    with tempfile.TemporaryDirectory(prefix="microcal-fuzz-") as tmp:
        for name in names:
            directory = Path(tmp) / name
            directory.mkdir()
            summary = fuzz(READERS[name], args.count, args.seed, directory)
            summary.print()
            sys.stdout.flush()
            failed |= summary.failed
            if summary.failed and args.shrink:
                for report in shrink(READERS[name], args.count, args.seed, directory):
                    print(f"    minimal: {report}")
    print(f"total {time.perf_counter() - start:.1f} s: {'FAILED' if failed else 'ok'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
