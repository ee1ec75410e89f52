#!/usr/bin/env python3
"""Compare gardefou's event-diagnosability verdicts with libFAUDES's own.

libFAUDES (PyPI package `faudes`) is the reference implementation of
event-diagnosability (`IsEventDiagnosable`). This script runs it on the models
listed in diagnoser/tests/fixtures/faudes/models.txt and

  --write        records its verdicts in diagnoser/tests/fixtures/faudes/expected.txt
                 (which `cargo test -p diagnoser --test it faudes` checks ours against);
  (default)      compares its verdicts with that file and with ours, obtained from
                 `cargo run -q -p diagnoser --example faudes_check`;
  --random N     also compares both on N random small generators (--seed S to
                 choose them), which reaches far more cases than the tutorial;
  --products N   also on N plants of two or three random components, sharing
                 events or not: libFAUDES checks their `Parallel`, we check the
                 components (`check --gen A.gen B.gen`).

A verdict is given for the whole failure-type map and for each failure type alone
(libFAUDES run on a map holding only that type).

Exit status: 0 when everything agrees, 1 on any disagreement (listed on stderr),
2 when libFAUDES or cargo cannot be run.

Needs python3 and `pip install faudes==2.34.5`.
"""

import argparse
import contextlib
import io
import os
import random
import re
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FIXTURES = os.path.join(ROOT, "diagnoser", "tests", "fixtures", "faudes")
MODELS = os.path.join(FIXTURES, "models.txt")
EXPECTED = os.path.join(FIXTURES, "expected.txt")

DIAG = "diagnosable"
NOT_DIAG = "not-diagnosable"
ERROR = "error"


def load_faudes():
    """Imports libFAUDES, silencing the notes it prints about optional modules."""
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            import faudes  # noqa: PLC0415
    except ImportError:
        sys.exit("faudes-compare: cannot import faudes: pip install faudes==2.34.5")
    return faudes


def faudes_version(faudes):
    try:
        from importlib.metadata import version  # noqa: PLC0415

        package = version("faudes")
    except Exception:  # noqa: BLE001
        package = "unknown"
    return f"{faudes.Version()} (PyPI faudes {package})"


def word(diagnosable):
    return DIAG if diagnosable else NOT_DIAG


def split_tokens(text):
    """Tokens of libFAUDES's own output: quoted names, tags and bare words."""
    return re.findall(r'"[^"]*"|<[^>]*>|[^\s<"]+', text)


def failure_types(faudes, fmap):
    """(type, [failure events]) of a libFAUDES FailureTypeMap, in its order."""
    types = []
    section = None
    for token in split_tokens(fmap.ToString()):
        if token.startswith("<"):
            name = token.strip("</>")
            closing = token.startswith("</") or name == "FailureTypes"
            section = None if closing else name
            continue
        name = token.strip('"')
        if section is None:
            types.append((name, []))
        elif section == "FailureEvents" and types:
            types[-1][1].append(name)
    return types


def libfaudes_verdicts(faudes, gen_path, map_path):
    """libFAUDES's verdict for the whole map, then per failure type:
    (verdict, [(type, verdict)]); ERROR when libFAUDES refuses the model."""
    with contextlib.redirect_stdout(io.StringIO()):
        try:
            system = faudes.System(gen_path)
            fmap = faudes.FailureTypeMap(map_path)
            overall = word(faudes.IsEventDiagnosable(system, fmap))
        except Exception:  # noqa: BLE001  (libFAUDES raises its own exception type)
            return ERROR, []
        per_type = []
        for name, events in failure_types(faudes, fmap):
            alone = faudes.FailureTypeMap()
            event_set = faudes.EventSet()
            for event in events:
                event_set.Insert(event)
            alone.AddFailureTypeMapping(name, event_set)
            try:
                per_type.append((name, word(faudes.IsEventDiagnosable(system, alone))))
            except Exception:  # noqa: BLE001
                per_type.append((name, ERROR))
    return overall, per_type


def format_verdicts(overall, per_type):
    return " ".join([overall] + [f"{name}={v}" for name, v in per_type])


def read_models():
    models = []
    with open(MODELS, encoding="utf-8") as fh:
        for number, line in enumerate(fh, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            fields = line.split()
            if len(fields) != 2:
                sys.exit(f"faudes-compare: {MODELS}:{number}: expected 'generator failure-types'")
            models.append((fields[0], fields[1]))
    return models


def read_expected():
    """{(generator, map): 'verdict T=verdict...'} from expected.txt."""
    expected = {}
    with open(EXPECTED, encoding="utf-8") as fh:
        for line in fh:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            fields = line.split()
            expected[(fields[0], fields[1])] = " ".join(fields[2:])
    return expected


def our_verdicts(pairs):
    """Our verdict lines, one per (generator, map) pair, from the Rust example."""
    args = [path for pair in pairs for path in pair]
    command = ["cargo", "run", "-q", "-p", "diagnoser", "--example", "faudes_check", "--"]
    try:
        done = subprocess.run(
            command + args, cwd=ROOT, capture_output=True, text=True, check=False
        )
    except OSError as error:
        print(f"faudes-compare: cannot run cargo: {error}", file=sys.stderr)
        sys.exit(2)
    lines = [l for l in done.stdout.splitlines() if l and not l[0].isspace()]
    if len(lines) != len(pairs):
        print(done.stderr, file=sys.stderr, end="")
        print(
            f"faudes-compare: faudes_check printed {len(lines)} verdicts for {len(pairs)} models",
            file=sys.stderr,
        )
        sys.exit(2)
    if done.returncode != 0:
        print(done.stderr, file=sys.stderr, end="")
    # Drop the generator path: the lines come in the order of the pairs.
    return [line.split(" ", 1)[1] if " " in line else "" for line in lines]


def random_model(rng, index, directory):
    """A random small generator and failure-type map, written to `directory`.

    Most states get a successor and most unobservable transitions go "forward" so
    that libFAUDES's assumptions hold often enough for the verdict to depend on the
    indeterminate cycles; a few models break them on purpose."""
    n = rng.randint(2, 6)
    observable = [f"o{i}" for i in range(1, rng.randint(1, 3) + 1)]
    unobservable = [f"u{i}" for i in range(1, rng.randint(0, 2) + 1)]
    failures = [f"f{i}" for i in range(1, rng.randint(1, 3) + 1)]
    hidden = unobservable + failures
    transitions = set()
    for x in range(1, n + 1):
        if rng.random() < 0.08:
            continue
        for _ in range(rng.randint(1, 3)):
            if hidden and rng.random() < 0.4:
                event = rng.choice(hidden)
                if x < n and rng.random() < 0.9:
                    y = rng.randint(x + 1, n)
                else:
                    y = rng.randint(1, n)
            else:
                event = rng.choice(observable)
                y = rng.randint(1, n)
            transitions.add((x, event, y))
    if rng.random() < 0.5 or len(failures) == 1:
        types = [("F", failures)]
    else:
        cut = rng.randint(1, len(failures) - 1)
        types = [("F1", failures[:cut]), ("F2", failures[cut:])]
    alphabet = " ".join(observable + [f"{e} +o+" for e in hidden])
    states = " ".join(str(x) for x in range(1, n + 1))
    trans = "\n".join(f'{x} "{e}" {y}' for x, e, y in sorted(transitions))
    gen_path = os.path.join(directory, f"random_{index:04}.gen")
    map_path = os.path.join(directory, f"random_{index:04}.txt")
    with open(gen_path, "w", encoding="utf-8") as fh:
        fh.write(
            f'<Generator> "random_{index}"\n<Alphabet> {alphabet} </Alphabet>\n'
            f"<States> {states} </States>\n<TransRel>\n{trans}\n</TransRel>\n"
            "<InitStates> 1 </InitStates>\n<MarkedStates> </MarkedStates>\n</Generator>\n"
        )
    with open(map_path, "w", encoding="utf-8") as fh:
        fh.write("<FailureTypes>\n")
        for name, events in types:
            quoted = " ".join(f'"{e}"' for e in events)
            fh.write(f'"{name}" <FailureEvents> {quoted} </FailureEvents>\n')
        fh.write("</FailureTypes>\n")
    return gen_path, map_path


def random_product(rng, index, directory):
    """Two or three random components over a common pool of events, each
    taking a random part of it (so that they share events or not), and a
    failure-type map; libFAUDES's `Parallel` of them written beside.
    Returns (comma-joined component paths, product path, map path)."""
    observable = ["o1", "o2", "o3", "o4"]
    hidden = ["u1", "f1", "f2", "f3"]
    alphabets = []
    for _ in range(rng.randint(2, 3)):
        alphabets.append([e for e in observable + hidden if rng.random() < 0.45]
                         or [rng.choice(observable)])
    # At least one failure, and only failures some component has (libFAUDES
    # refuses a map naming an event of no component).
    if not any(e.startswith("f") for mine in alphabets for e in mine):
        alphabets[0].append("f1")
    present = {e for mine in alphabets for e in mine}
    paths = []
    for c, mine in enumerate(alphabets):
        n = rng.randint(1, 4)
        transitions = set()
        for x in range(1, n + 1):
            for _ in range(rng.randint(0, 3)):
                event = rng.choice(mine)
                if event in hidden and x < n and rng.random() < 0.8:
                    y = rng.randint(x + 1, n)
                else:
                    y = rng.randint(1, n)
                transitions.add((x, event, y))
        alphabet = " ".join(e if e in observable else f"{e} +o+" for e in mine)
        path = os.path.join(directory, f"product_{index:04}_{c}.gen")
        with open(path, "w", encoding="utf-8") as fh:
            fh.write(
                f'<Generator> "c{c}"\n<Alphabet> {alphabet} </Alphabet>\n'
                f"<States> {' '.join(str(x) for x in range(1, n + 1))} </States>\n<TransRel>\n"
                + "\n".join(f'{x} "{e}" {y}' for x, e, y in sorted(transitions))
                + "\n</TransRel>\n<InitStates> 1 </InitStates>\n</Generator>\n"
            )
        paths.append(path)
    failures = [e for e in ("f1", "f2", "f3") if e in present]
    if rng.random() < 0.5 or len(failures) == 1:
        types = [("F", failures)]
    else:
        types = [("F1", failures[:1]), ("F2", failures[1:])]
    map_path = os.path.join(directory, f"product_{index:04}.txt")
    with open(map_path, "w", encoding="utf-8") as fh:
        fh.write("<FailureTypes>\n")
        for name, events in types:
            fh.write(f'"{name}" <FailureEvents> {" ".join(events)} </FailureEvents>\n')
        fh.write("</FailureTypes>\n")
    return ",".join(paths), map_path


def libfaudes_product(faudes, components, directory, index):
    """libFAUDES's `Parallel` of the components, written to a file."""
    with contextlib.redirect_stdout(io.StringIO()):
        systems = [faudes.System(path) for path in components.split(",")]
        result = systems[0]
        for other in systems[1:]:
            composed = faudes.System()
            faudes.Parallel(result, other, composed)
            result = composed
        path = os.path.join(directory, f"product_{index:04}.gen")
        result.Write(path)
    return path


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", action="store_true", help="regenerate expected.txt")
    parser.add_argument("--random", type=int, default=0, metavar="N",
                        help="also compare on N random generators")
    parser.add_argument("--products", type=int, default=0, metavar="N",
                        help="also compare on N random plants of several components")
    parser.add_argument("--seed", type=int, default=1, help="seed of the random generators")
    options = parser.parse_args()
    faudes = load_faudes()
    models = read_models()
    theirs = {
        (g, m): format_verdicts(*libfaudes_verdicts(
            faudes, os.path.join(FIXTURES, g), os.path.join(FIXTURES, m)))
        for g, m in models
    }

    if options.write:
        with open(EXPECTED, "w", encoding="utf-8") as fh:
            fh.write(
                f"# Verdicts of {faudes_version(faudes)} on the models of models.txt:\n"
                "# generator, failure-type map, IsEventDiagnosable's verdict for the map,\n"
                "# then its verdict for each failure type alone.\n"
                "# Written by scripts/faudes-compare.py --write: do not edit.\n"
            )
            for g, m in models:
                fh.write(f"{g} {m} {theirs[(g, m)]}\n")
        print(f"faudes-compare: wrote {len(models)} verdicts to {os.path.relpath(EXPECTED)}")
        return 0

    problems = []
    expected = read_expected()
    for g, m in models:
        if (g, m) not in expected:
            problems.append(f"{g} {m}: not in expected.txt (run with --write)")
        elif expected[(g, m)] != theirs[(g, m)]:
            problems.append(
                f"{g} {m}: expected.txt says '{expected[(g, m)]}', "
                f"libFAUDES now says '{theirs[(g, m)]}'"
            )
    for g, m in expected:
        if (g, m) not in theirs:
            problems.append(f"{g} {m}: in expected.txt but not in models.txt")

    pairs = [(os.path.join(FIXTURES, g), os.path.join(FIXTURES, m)) for g, m in models]
    labels = [f"{g} {m}" for g, m in models]
    verdicts = [theirs[model] for model in models]

    scratch = None
    if options.random > 0 or options.products > 0:
        scratch = tempfile.mkdtemp(prefix="faudes-compare-")
        rng = random.Random(options.seed)
        # (what we check, its map, what libFAUDES checks): a product's
        # components against libFAUDES's Parallel of them.
        cases = []
        for index in range(options.random):
            gen_path, map_path = random_model(rng, index, scratch)
            cases.append((gen_path, map_path, gen_path))
        for index in range(options.products):
            components, map_path = random_product(rng, index, scratch)
            cases.append((components, map_path,
                          libfaudes_product(faudes, components, scratch, index)))
        for ours_path, map_path, theirs_path in cases:
            verdict = format_verdicts(*libfaudes_verdicts(faudes, theirs_path, map_path))
            if verdict.startswith(ERROR):
                continue
            pairs.append((ours_path, map_path))
            labels.append(f"{ours_path} {map_path}")
            verdicts.append(verdict)

    ours = our_verdicts(pairs)
    width = max(len(l) for l in labels[: len(models)])
    for label, theirs_line, ours_line in list(zip(labels, verdicts, ours))[: len(models)]:
        if theirs_line.startswith(ERROR):
            problems.append(f"{label}: libFAUDES cannot check this model")
        if ours_line.startswith(ERROR):
            problems.append(f"{label}: faudes_check cannot check this model")
    for label, theirs_line, ours_line in zip(labels, verdicts, ours):
        if theirs_line != ours_line:
            problems.append(f"{label}: libFAUDES says '{theirs_line}', we say '{ours_line}'")
    for label, theirs_line, ours_line in list(zip(labels, verdicts, ours))[: len(models)]:
        mark = "ok " if theirs_line == ours_line else "DIFF"
        print(f"{mark} {label:<{width}}  libFAUDES: {theirs_line}  ours: {ours_line}")
    if options.random > 0 or options.products > 0:
        compared = len(pairs) - len(models)
        agreed = sum(
            1 for t, o in list(zip(verdicts, ours))[len(models):] if t == o
        )
        diagnosable = sum(1 for t in verdicts[len(models):] if t.startswith(DIAG))
        print(
            f"random generators and plants (seed {options.seed}): {agreed}/{compared} agree, "
            f"{diagnosable} diagnosable for libFAUDES"
        )

    if problems:
        for problem in problems:
            print(f"faudes-compare: {problem}", file=sys.stderr)
        if scratch:
            print(f"faudes-compare: random models kept in {scratch}", file=sys.stderr)
        print(f"faudes-compare: {len(problems)} disagreement(s)", file=sys.stderr)
        return 1
    if scratch:
        for name in os.listdir(scratch):
            os.remove(os.path.join(scratch, name))
        os.rmdir(scratch)
    print(f"faudes-compare: libFAUDES and gardefou agree on all {len(pairs)} models")
    return 0


if __name__ == "__main__":
    sys.exit(main())
