#!/usr/bin/env python3
"""Writes a libFAUDES generator of N identical turntables, each of which may
lose its C5 sensor (stuck at 0), and its failure-type map: the product of
independent components, the case where a verifier's state space grows as the
product of theirs.

    scripts/turntable-product.py [--both] N OUT.gen OUT-failures.txt

A turntable i: at C4, the order `a_i` sends the plate off; `c5_i` (C5 rises)
says it reached C5; releasing it (`r_i`) brings it back, and `c4_i` (C4 rises)
says it is home. The failure `f_i` (unobservable) can happen at C4; after it,
the plate's arrival is the unobservable `m_i`. Every event but `f_i` and `m_i`
is observable. 8 states per turntable, 8^N in the product: N = 4 gives 4,096,
N = 5 32,768, N = 6 262,144.

With --both, C5 may also stick at 1 (`g_i`, then the unobservable `n_i`):
12 states per turntable and two failure types, F0 and F1; N = 4 gives 20,736
states, N = 5 248,832.
"""
import itertools
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
    both = args[0] == "--both"
    if both:
        args = args[1:]
    n, gen_path, map_path = int(args[0]), args[1], args[2]
    one = ONE + STUCK1 if both else ONE
    names = ["a", "c5", "r", "c4", "f", "m"] + (["g", "n"] if both else [])
    alphabet = []
    for i in range(n):
        for e in names:
            name = f'"{e}_{i}"'
            alphabet.append(name + " +o+" if e in ("f", "m", "g", "n") else name)
    states = list(itertools.product(range(12 if both else 8), repeat=n))
    number = {s: k + 1 for k, s in enumerate(states)}
    with open(gen_path, "w") as out:
        out.write('<Generator>\n"product"\n<Alphabet>\n')
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
                        out.write(f'{number[s]} "{e}_{i}" {number[t]}\n')
        out.write("</TransRel>\n<InitStates>\n1\n</InitStates>\n<MarkedStates>\n</MarkedStates>\n</Generator>\n")
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
