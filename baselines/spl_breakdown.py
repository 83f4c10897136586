"""Where does a policy's SPL go? Two `evaluate.py` JSONs of the same policy on the same seeds, one on the FCN's box
(with the reference: SPL) and one on the ground truth's, put each episode in one class and sum what it lost
(1 - SPL, over all episodes, so that the classes add up to 1 - SPL):

- "not solved";
- "a lost glimpse": the target in view at the first step (the search pose), solved `LATE` or more steps later
  than on the ground truth's box: the FCN turned the first view away and the orbit went round;
- "far side": first seen after `FAR` or more steps, when the orbit has come back from joint 1's limit (SPL's
  reference knows which way to turn first; an agent that does not pays this on about half the scenes);
- "the rest".

    python baselines/evaluate.py --policy explore --then dqn --checkpoint agents/weights/dqn.pt --episodes 50 \\
        --env.object-set unseen --json outputs/teacher_fcn.json
    python baselines/evaluate.py --policy explore --then dqn --checkpoint agents/weights/dqn.pt --episodes 50 \\
        --env.object-set unseen --env.box-source ground_truth --no-reference --json outputs/teacher_gt.json
    python baselines/spl_breakdown.py --fcn outputs/teacher_fcn.json --ground-truth outputs/teacher_gt.json
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import tyro

LATE = 25
"""steps later than on the ground truth's box that make a first-step sighting "lost" """
FAR = 30
"""steps to first see the target from which it was on the far side"""
CLASSES = ("not solved", "a lost glimpse", "far side", "the rest")


@dataclass
class Args:
    fcn: str
    """evaluate.py's JSON on the FCN's box, with the reference (its episodes' SPL)"""
    ground_truth: str
    """evaluate.py's JSON of the same policy and seeds on the ground truth's box"""


def episode_class(fcn: dict, ground_truth: dict) -> str:
    """The class (CLASSES) of one episode from its two runs' per-episode metrics."""
    if not fcn["success"]:
        return "not solved"
    seen, solved, reference = fcn["steps_to_see"], fcn["steps_to_success"], ground_truth["steps_to_success"]
    if seen == 1 and reference is not None and not math.isnan(reference) and solved - reference >= LATE:
        return "a lost glimpse"
    if seen is not None and seen >= FAR:
        return "far side"
    return "the rest"


def breakdown(fcn: list[dict], ground_truth: list[dict]) -> dict[str, tuple[int, float]]:
    """class -> (episodes, SPL lost as a share of all episodes); the episodes must be the same seeds in order."""
    if [e["seed"] for e in fcn] != [e["seed"] for e in ground_truth]:
        raise ValueError("the two evaluations must be of the same seeds, in the same order")
    if any(e["spl"] is None for e in fcn):
        raise ValueError("the FCN box's evaluation has no SPL: run evaluate.py with its reference (the default)")
    table = {name: (0, 0.0) for name in CLASSES}
    for a, b in zip(fcn, ground_truth):
        name = episode_class(a, b)
        count, lost = table[name]
        table[name] = (count + 1, lost + (1.0 - a["spl"]) / len(fcn))
    return table


def main(args: Args) -> dict[str, tuple[int, float]]:
    with open(args.fcn) as f, open(args.ground_truth) as g:
        fcn, ground_truth = json.load(f)["episodes"], json.load(g)["episodes"]
    table = breakdown(fcn, ground_truth)
    spl = sum(e["spl"] for e in fcn) / len(fcn)
    print(f"SPL {spl:.3f} over {len(fcn)} episodes; lost:\n\n| episodes | count | SPL lost |\n|---|---|---|")
    for name, (count, lost) in table.items():
        print(f"| {name} | {count} | {lost:.3f} |")
    return table


if __name__ == "__main__":
    main(tyro.cli(Args))
