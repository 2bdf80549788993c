"""How far the chain diagnosis is from diagnosing planar campaigns (issue 22, "a planar
campaign is a chain campaign whose sensor sees x, y"): the planar validation's campaigns
(:mod:`cell.diagnosis.validate`, the independent truth of :mod:`cell.truth`), each
diagnosed twice in the same run: by the planar diagnosis, and by the chain diagnosis of the
campaign read as a chain campaign (:func:`cell.measurements.chain.planar_as_chain`: two
revolute joints in DH, the tool centre a known marker, a sensor that sees x and y; each
sample of a measured move a pose at the commanded angles). Prints, per engine, the verdict
counts, the median CPU seconds of one diagnosis in this process, and the confident wrong
answers, then the verdicts side by side per true effect.

    .venv/bin/python bench/bench_planar_as_chain.py [--trials 60] [--seed 1] [--outside 0]
"""
from __future__ import annotations

import argparse
from collections import Counter

from cell.diagnosis import validate
from cell.truth.verdict import VERDICTS


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=60)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--outside", type=float, default=0.0, help="share of truths outside the vocabulary")
    a = ap.parse_args(argv)
    runs = {engine: [validate.run_trial(i, a.seed, outside_share=a.outside, engine=engine)
                     for i in range(a.trials)] for engine in validate.ENGINES}
    print(f"Planar validation, {a.trials} campaigns, seed {a.seed}, share outside the vocabulary "
          f"{a.outside:g}: both engines on the same campaigns\n")
    print("| engine | " + " | ".join(VERDICTS) + " | CPU s median |")
    print("|---|" + "---:|" * (len(VERDICTS) + 1))
    for engine, ts in runs.items():
        c = Counter(t.verdict for t in ts)
        cpu = sorted(t.seconds for t in ts)[len(ts) // 2]
        print(f"| {engine} | " + " | ".join(str(c[v]) for v in VERDICTS) + f" | {cpu:.2f} |")
    for engine, ts in runs.items():
        for t in ts:
            if t.verdict == "wrong":
                print(f"\n- {engine}, trial {t.index}: truth {t.truth_label}, answered "
                      f"{t.answer_label} (confidence {t.confidence})", end="")
    print("\n\n| true effect | trials | planar | chain |\n|---|---:|---|---|")
    kinds = sorted({t.true_effect for t in runs["planar"]})
    for k in kinds:
        pairs = [(p, c) for p, c in zip(runs["planar"], runs["chain"]) if p.true_effect == k]
        show = lambda ts: ", ".join(f"{v} {n}" for v, n in Counter(ts).most_common())  # noqa: E731
        print(f"| {k} | {len(pairs)} | {show(p.verdict for p, _ in pairs)} | "
              f"{show(c.verdict for _, c in pairs)} |")


if __name__ == "__main__":
    main()
