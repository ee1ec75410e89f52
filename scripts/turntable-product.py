#!/usr/bin/env python3
"""Writes a libFAUDES generator of N identical turntables, each of which may
lose its C5 sensor (stuck at 0), and its failure-type map: the product of
independent components, the case where a verifier's state space grows as the
product of theirs.

    scripts/turntable-product.py [--both] N OUT.gen OUT-failures.txt
    scripts/turntable-product.py [--both] --components N DIR OUT-failures.txt

A turntable i: at C4, the order `a_i` sends the plate off; `c5_i` (C5 rises)
says it reached C5; releasing it (`r_i`) brings it back, and `c4_i` (C4 rises)
says it is home. The failure `f_i` (unobservable) can happen at C4; after it,
the plate's arrival is the unobservable `m_i`. Every event but `f_i` and `m_i`
is observable. 8 states per turntable, 8^N in the product: N = 4 gives 4,096,
N = 5 32,768, N = 6 262,144.

With --components, each turntable is its own generator, DIR/turntable_i.gen
(`check --gen DIR/*.gen` composes them).

With --both, C5 may also stick at 1 (`g_i`, then the unobservable `n_i`):
12 states per turntable and two failure types, F0 and F1; N = 4 gives 20,736
states, N = 5 248,832.
"""
import itertools
import os
import sys

# (state, event, next) of one turntable; states 0-3 normal, 4-7 after f.
ONE = [
    (0, "a", 1), (1, "c5", 2), (2, "r", 3), (3, "c4", 0),
    (0, "f", 4),
    (4, "a", 5), (5, "m", 6), (6, "r", 7), (7, "c4", 4),
]
# Stuck at 1: the same cycle, its arrival unobservable too.
STUCK1 = [
    (0, "g", 8),
    (8, "a", 9), (9, "n", 10), (10, "r", 11), (11, "c4", 8),
]


def main():
    args = sys.argv[1:]
    both = "--both" in args
    components = "--components" in args
    args = [a for a in args if a not in ("--both", "--components")]
    n, gen_path, map_path = int(args[0]), args[1], args[2]
    one = ONE + STUCK1 if both else ONE
    names = ["a", "c5", "r", "c4", "f", "m"] + (["g", "n"] if both else [])
    write_map(n, both, map_path)
    if components:
        os.makedirs(gen_path, exist_ok=True)
        for i in range(n):
            write_product(1, one, names, both, os.path.join(gen_path, f"turntable_{i}.gen"), i,
                          f"turntable_{i}")
    else:
        write_product(n, one, names, both, gen_path, 0, "product")


def write_product(n, one, names, both, gen_path, first, title):
    """The product of turntables first..first+n-1 as one generator."""
    alphabet = []
    for i in range(first, first + n):
        for e in names:
            name = f'"{e}_{i}"'
            alphabet.append(name + " +o+" if e in ("f", "m", "g", "n") else name)
    states = list(itertools.product(range(12 if both else 8), repeat=n))
    number = {s: k + 1 for k, s in enumerate(states)}
    with open(gen_path, "w") as out:
        out.write(f'<Generator>\n"{title}"\n<Alphabet>\n')
        out.write("\n".join(alphabet) + "\n</Alphabet>\n<States>\n")
        out.write(f"1 - {len(states)}\n</States>\n<TransRel>\n" if False else "")
        for s in states:
            out.write(f"{number[s]}\n")
        out.write("</States>\n<TransRel>\n")
        for s in states:
            for i in range(n):
                for (x, e, y) in one:
                    if s[i] == x:
                        t = s[:i] + (y,) + s[i + 1:]
                        out.write(f'{number[s]} "{e}_{first + i}" {number[t]}\n')
        out.write("</TransRel>\n<InitStates>\n1\n</InitStates>\n<MarkedStates>\n</MarkedStates>\n</Generator>\n")


def write_map(n, both, map_path):
    with open(map_path, "w") as out:
        out.write("<FailureTypes>\n")
        types = [("F0", "f"), ("F1", "g")] if both else [("F", "f")]
        for name, event in types:
            out.write(f'"{name}"\n<FailureEvents>\n')
            out.write("\n".join(f'"{event}_{i}"' for i in range(n)))
            out.write("\n</FailureEvents>\n")
        out.write("</FailureTypes>\n")


if __name__ == "__main__":
    main()
