"""Do the 3-view students' errors average out? Their mean action against each one alone.

The students of the shipped 3-view recipe reach 0.765 / 0.770 / 0.770 of the blocked test
tasks over three training seeds, with blocked collision rates 0.135-0.170, while their teacher
reaches 1.000. If the gap were the variance of regressing on one run's data (half the data
costs 0.13 blocked, `results/stage2/distill/README.md`), the mean action of students trained
on different seeds would do clearly better than each; if it is a bias they share (what the
architecture, the views or the labels allow), the mean would do about as well as each.

Members: the shipped `residual-3views` (seed 0) and the retrained seeds 1 and 2
(`runs/reseed/d3-seed1|2/policy.pt`, `results/stage2/shield/camera_hybrid_seeds.py`). Each
member alone and their mean (`MeanActionPolicy`: the average of the members' deterministic
actions) run on the same `--num-blocked` blocked and `--num-standard` standard validation
tasks from `--offset` into the validation range (70000: a block no earlier check used); one
JSON line per (policy, family) goes to ensemble.jsonl (per task: success, collision,
steps; the run's median act), skipping what is there. `--summary` prints success and
collision rates with Wilson 95% intervals, and how often the mean succeeds where a member
fails and the other way round (with the exact two-sided sign test's P on those tasks; the
same for the `distilled` student against its control).

Then whether one network can hold what the mean knows: `STUDENTS` are fresh students
regressed on the pooled DAgger data of seeds 1 and 2, once with the members' mean action as
the label and once with the teacher's (the control), same tasks.

    python results/stage2/ensemble/ensemble.py
    python results/stage2/ensemble/ensemble.py --policies distilled pooled
    python results/stage2/ensemble/ensemble.py --summary
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
OUT = HERE / "ensemble.jsonl"
SHIPPED_BEFORE = HERE / "shipped_until_session24"
MEMBERS = {
    # The shipped students until session 24 (pinned copies: the package's files moved on).
    "seed0": str(SHIPPED_BEFORE / "residual-3views.pt"),
    "seed1r": str(ROOT / "runs" / "reseed" / "d3-seed1" / "policy.pt"),
    "seed2r": str(ROOT / "runs" / "reseed" / "d3-seed2" / "policy.pt"),
}
MEAN = "mean"
SEEDS = HERE / "seeds"
LEVERS33 = HERE / "levers33"
GUARDED = {
    "3v-s5+hybrid": ("3v-s5", True),
    **{f"3v-s{seed}+shield": (f"3v-s{seed}", False) for seed in (5, 7, 8)},
}
"""Session 27: the shipped 3-view student through the hybrid's depth shield (`HYBRID[3]`),
without or with its planner (which tasks the safety layer turns into successes); session 31:
the other two seeds through the shield."""
UNSEEN = {"shadow_m": 0.05, "shadow_behind_surfaces": True}
"""The 1-view hybrid's unseen-space test: the hand keeps out of space no camera has seen free
within 5 cm behind seen surfaces."""
ESCAPE_VARIANTS = {
    "long": {"burst_steps": 10},
    "soon": {"after_steps": 5},
    "long-soon": {"burst_steps": 10, "after_steps": 5},
}
"""Session 31, second round: escapes twice as long, after half as many stalled steps, both."""
SHIELDED_BURST = {
    **{f"3v-s{seed}+shield+burst": (f"3v-s{seed}", {}, {}, None) for seed in (5, 7, 8)},
    **{
        f"3v-s{seed}+shield+burst-half": (f"3v-s{seed}", {"scale": 0.5}, {}, None)
        for seed in (5, 7, 8)
    },
    **{f"3v-s{seed}+shield-unseen+burst": (f"3v-s{seed}", {}, UNSEEN, None) for seed in (5, 7, 8)},
    **{
        f"3v-s{seed}+shield-unseen+burst-{name}": (f"3v-s{seed}", options, UNSEEN, None)
        for seed in (5, 7, 8)
        for name, options in ESCAPE_VARIANTS.items()
    },
    **{
        f"3v-s{seed}+shield-unseen+burst-{mode}": (f"3v-s{seed}", {}, UNSEEN, mode)
        for seed in (5, 7, 8)
        for mode in ("free", "open")
    },
}
"""Session 31: (student, `StallBurst` options, changes to the shield, `EscapeChooser` mode or
None): random escapes from stalls (`stall.StallBurst`, its defaults but for the options given)
inside the hybrid's depth shield without its planner (with the changes given): the shield stops
the escapes that would run into an obstacle (session 29's bursts on the bare students collided
as often as they arrived)."""
SWITCHED = {f"3v-s{seed}+escape": (f"3v-s{seed}", "3v-escape10") for seed in (5, 7, 8)}
"""Session 28: each 3-view seed acting, the escape student instead once the episode has
stalled 10 steps (`clamgen.experiments.stall.StallSwitch`)."""
CROP_OFFSETS = ((4, 4), (0, 0), (0, 8), (8, 0), (8, 8))
"""Session 28: the centre crop the students act on and the four corner crops of their training's
random crops (64-pixel views, 56-pixel crops), every view alike."""
CROPPED = {f"3v-s{seed}+crops": f"3v-s{seed}" for seed in (5, 7, 8)}
"""Each 3-view seed acting with the mean of its pre-squash means over `CROP_OFFSETS`."""


BURST = {
    "3v-s5+burst": ("3v-s5", {}),
    "3v-s5+burst20": ("3v-s5", {"after_steps": 20}),
    **{f"3v-s{seed}+burst-half": (f"3v-s{seed}", {"scale": 0.5}) for seed in (5, 7, 8)},
}
"""Session 29: a 3-view seed with random escapes from its stalls (`stall.StallBurst`, its
defaults but for the options given)."""
NEAR_BASE = {
    f"3v-reg-s{seed}+base{cm}": (f"3v-reg-s{seed}", cm / 100) for seed in (7, 8, 9) for cm in (3, 5)
}
"""Session 52: a 3-view regression acting with its base alone within the given distance (m) of
the target (`NearTargetBase`; README, "The base near the target")."""
AMPLIFIED = {"3v-s5+amplify": "3v-s5"}
"""Session 29: a 3-view seed whose command, while its episode has stalled 10 steps or more, is
scaled up until its largest joint command is 1 (`StallSwitch` to `SaturatedPolicy`)."""
LEARNED_SHIELD = {
    **{
        f"3v-s5+learned{threshold}": (
            "3v-s5",
            ROOT / "runs" / "learned-shield" / "3v-s5",
            threshold,
        )
        for threshold in ("0.1", "0.5")
    },
    **{
        f"3v-s{seed}+learned0.3": (
            f"3v-s{seed}",
            ROOT / "runs" / "learned-shield" / f"3v-s{seed}",
            "0.3",
        )
        for seed in (5, 7, 8)
    },
    "3v-rows147k-coll+head": (
        "3v-rows147k-coll",
        ROOT / "runs" / "offline" / "d3-rows147k-coll",
        "0.3",
    ),
}
"""Session 29: a 3-view seed through a collision head on its own encoding
(`clamgen.experiments.learned_shield`, fitted by `../shield/learned_shield.py`: its
directory, the threshold)."""
BY_CRITIC = {f"priv-ft-{tag}+critic": f"priv-ft-{tag}" for tag in ("a1", "a1-100k", "a1-100k-n5")}
"""Session 30: fine-tuned students acting by their critic (the best of
`CRITIC_CANDIDATES` candidates around the mean by the fine-tuned Q, `SACPolicy`'s
`critic_candidates`): the critic learnt that a collision ends an episode at a cost."""
HEADED = {
    "3v-rows147k-chunk+ens": ("3v-rows147k-chunk", "chunks", "ChunkEnsemblePolicy"),
    "3v-rows147k-bins+head": ("3v-rows147k-bins", "bins", "BinPolicy"),
}
"""Students acting through a head regressed beside them (`../distill/MODULE.py`: the student,
the module, its policy class, which reads the module's `HEAD_NAME` beside the student's
policy file): session 28's chunk student with temporal ensembling, session 29's bin student
with its bin head."""
STUDENTS = {
    "distilled": str(ROOT / "runs" / "offline" / "d3-ens" / "policy.pt"),
    "pooled": str(ROOT / "runs" / "offline" / "d3-pool" / "policy.pt"),
    "one-run": str(ROOT / "runs" / "offline" / "d3-one" / "policy.pt"),
    # 2 views: the shipped student, the retrained seed 4, and a student regressed on the
    # pooled data of the 2-view seed-4 run and both 3-view runs (their first two cameras).
    "2v-seed0": str(SHIPPED_BEFORE / "residual-2views.pt"),
    "2v-seed4r": str(ROOT / "runs" / "reseed" / "d2-seed4" / "policy.pt"),
    "2v-pooled": str(ROOT / "runs" / "offline" / "d2-pool" / "policy.pt"),
    # 1 view: the shipped student, and one regressed on the same three runs' first camera.
    "1v-seed0": str(SHIPPED_BEFORE / "residual-1view.pt"),
    "1v-pooled": str(ROOT / "runs" / "offline" / "d1-pool" / "policy.pt"),
    # Session 22: the same regression on two more 3-view runs' data (seeds 3 and 4), compared
    # task by task with the students on fewer runs (README, "Four runs' data").
    "3v-pool4": str(ROOT / "runs" / "offline" / "d3-pool4" / "policy.pt"),
    "2v-pool5": str(ROOT / "runs" / "offline" / "d2-pool5" / "policy.pt"),
    "1v-pool5": str(ROOT / "runs" / "offline" / "d1-pool5" / "policy.pt"),
    # ... and the four-run 3-view student regressed twice as long (48000 steps).
    "3v-pool4-48k": str(ROOT / "runs" / "offline" / "d3-pool4-48k" / "policy.pt"),
    # Session 23: the five-run 2- and 1-view students regressed twice as long too.
    "2v-pool5-48k": str(ROOT / "runs" / "offline" / "d2-pool5-48k" / "policy.pt"),
    "1v-pool5-48k": str(ROOT / "runs" / "offline" / "d1-pool5-48k" / "policy.pt"),
    # ... and DAgger continued from the 48000-step 3-view student (`continue_dagger.py`).
    # (each a continuation's iteration file: policy.pt moves on when a continuation resumes)
    "3v-dagger+2": str(ROOT / "runs" / "offline" / "d3-pool4-48k-dagger" / "policy_iteration1.pt"),
    "2v-dagger+2": str(ROOT / "runs" / "offline" / "d2-pool5-48k-dagger" / "policy_iteration1.pt"),
    "3v-dagger+4": str(ROOT / "runs" / "offline" / "d3-pool4-48k-dagger" / "policy_iteration3.pt"),
    "1v-dagger+2": str(ROOT / "runs" / "offline" / "d1-pool5-48k-dagger" / "policy_iteration1.pt"),
    "2v-dagger+4": str(ROOT / "runs" / "offline" / "d2-pool5-48k-dagger" / "policy_iteration3.pt"),
    "3v-dagger+2-s6": str(
        ROOT / "runs" / "offline" / "d3-pool4-48k-dagger-s6" / "policy_iteration1.pt"
    ),
    # Session 27: the three 3-view seeds (committed policy files; seed 5 is the shipped one)
    # and one student regressed on their mean action over the rebuilt four-run pool.
    "3v-s5": str(HERE / "3v-dagger+2_policy.pt"),
    "3v-s7": str(SEEDS / "d3_seed7_policy.pt"),
    "3v-s8": str(SEEDS / "d3_seed8_policy.pt"),
    "3v-s9": str(SEEDS / "d3_seed9_policy.pt"),  # session 32's fourth seed of the recipe
    "3v-mean578-distilled": str(ROOT / "runs" / "offline" / "d3-mean578" / "policy.pt"),
    # ... the students' teacher without its lookahead (true obstacle poses, acting reactively;
    # renders nothing): does a reactive policy that sees the poses exactly fail the same tasks?
    "teacher-reactive": str(ROOT / "results" / "stage2" / "distill" / "teacher" / "policy.pt"),
    # ... and the regressions of seeds 7 and 8 before their continuation (`3v-reg-s7|8`, now
    # below: their files were lost with a machine), against the same regressions with the
    # states near their target drawn three times as often.
    **{
        f"3v-near3-s{seed}": str(ROOT / "runs" / "offline" / f"d3-near3-s{seed}" / "policy.pt")
        for seed in (7, 8)
    },
    # Session 33: the regressions of seeds 7, 8 and 9 and three levers on seed 7's: 32 conv
    # channels instead of 16 (`offline.py --encoder-channels 32`), 96000 regression steps
    # instead of 48000, and no view dropout in the regression (`--view-dropout 0`); all six on
    # the pool rebuilt in session 34 (`lever_lane.sh`), their files committed as each finished
    # (block 180000's `3v-reg-s7|8` lines came from the lost pool's regressions).
    **{
        name: str(LEVERS33 / f"{stem}_policy.pt")
        for name, stem in (
            *((f"3v-reg-s{seed}", f"d3-pool4-48k-s{seed}") for seed in (7, 8, 9)),
            ("3v-wide32-s7", "d3-wide32-s7"),
            ("3v-reg96k-s7", "d3-pool4-96k-s7"),
            ("3v-nodrop-s7", "d3-nodrop-s7"),
            # Session 35: eight runs' data (the four and four more DAgger runs), 96000 steps.
            ("3v-pool8-s7", "d3-pool8-96k-s7"),
            ("3v-pool8-s8", "d3-pool8-96k-s8"),  # session 36: a second seed beside it
            ("3v-pool7-s7", "d3-pool7-96k-s7"),  # its fallback (seven runs), if too slow
            # Session 37: four DAgger runs whose lookahead keeps the clean plan of least
            # deviation (`rebuild_pool.sh --least-offset`), the shipped recipe's regression
            # otherwise.
            ("3v-least4-s7", "d3-least4-48k-s7"),
            # Session 50: four DAgger runs whose students read the previous action
            # (`rebuild_pool.sh --previous-action`), the shipped recipe's regression otherwise.
            ("3v-prev4-s7", "d3-prev4-48k-s7"),
            ("3v-prev4-s8", "d3-prev4-48k-s8"),
            # Session 52: prev4's regression with the loss after the tanh (`lever_lane.sh
            # tanh-prev4-sS`; distill README, "The loss after the tanh").
            ("3v-tanh-prev4-s7", "d3-tanh-prev4-48k-s7"),
            # Session 53: prev4's regression, the student also reading the tip's offset to the
            # goal (`lever_lane.sh goal-prev4-sS`; distill README, "The tip's offset to the
            # goal").
            ("3v-goal-prev4-s7", "d3-goal-prev4-48k-s7"),
            ("3v-goal-prev4-s8", "d3-goal-prev4-48k-s8"),
            # ... and the same regression on centre crops (`lever_lane.sh center-prev4-sS`;
            # README, "Centre crops in the regression").
            ("3v-center-prev4-s7", "d3-center-prev4-48k-s7"),
            ("3v-center-prev4-s8", "d3-center-prev4-48k-s8"),
            # ... and on random crops shifted up to 8 pixels (`lever_lane.sh shift8-prev4-sS`;
            # README, "Wider random shifts in the regression").
            ("3v-shift8-prev4-s7", "d3-shift8-prev4-48k-s7"),
            ("3v-shift8-prev4-s8", "d3-shift8-prev4-48k-s8"),
            # Session 54: ... with the learning rate decayed to 0 along a cosine over the
            # regression (`lever_lane.sh cos-prev4-sS`; README, "A decaying learning rate").
            ("3v-cos-prev4-s7", "d3-cos-prev4-48k-s7"),
            ("3v-cos-prev4-s8", "d3-cos-prev4-48k-s8"),
            # ... and with decoupled weight decay 0.1 / 1 (`lever_lane.sh wd0.1|wd1-prev4-sS`;
            # README, "Weight decay in the regression").
            ("3v-wd0.1-prev4-s7", "d3-wd0.1-prev4-48k-s7"),
            ("3v-wd1-prev4-s7", "d3-wd1-prev4-48k-s7"),
            # ... and with the states whose tip is within 5 cm of the target drawn three times
            # as often (`lever_lane.sh tip3-prev4-sS`; README, "Near-target states weighted").
            ("3v-tip3-prev4-s7", "d3-tip3-prev4-48k-s7"),
            ("3v-tip3-prev4-s8", "d3-tip3-prev4-48k-s8"),
            # Session 55: ... with a spatial-softmax encoder, on the recipe's conv strides
            # 2, 2, 1, 1 and on 2, 1, 1, 1 (`lever_lane.sh ssm-prev4-sS` / `ssm21-prev4-sS`;
            # README, "A keypoint encoder").
            ("3v-ssm-prev4-s7", "d3-ssm-prev4-48k-s7"),
            ("3v-ssm21-prev4-s7", "d3-ssm21-prev4-48k-s7"),
            # ... and the previous-action pool's regressions continued two DAgger iterations
            # as the shipped recipe's (README, "The previous-action pool's student, continued").
            ("3v-prev4-s7-dagger+2", "d3-prev4-48k-s7-dagger"),
            ("3v-prev4-s8-dagger+2", "d3-prev4-48k-s8-dagger"),
            # ... and the same with noise on the student's actions while it drives (DART;
            # README, "The continuation with noise on the student's actions").
            ("3v-prev4-s7-dart+2", "d3-prev4-48k-s7-dart"),
            ("3v-prev4-s8-dart+2", "d3-prev4-48k-s8-dart"),
        )
    },
    # Session 54: prev4's regression with 32 conv channels instead of 16 (`lever_lane.sh
    # wide32-prev4-sS`; README, "The wider encoder on the previous-action pool"): read from
    # runs/offline, not committed (10 MB a student; the lever stopped).
    **{
        f"3v-wide32-prev4-s{seed}": str(
            ROOT / "runs" / "offline" / f"d3-wide32-prev4-48k-s{seed}" / "policy.pt"
        )
        for seed in (7, 8)
    },
    # Session 28: a privileged student (the teacher's architecture: true obstacle poses and arm
    # keypoints, nothing rendered) regressed on the same four-run pool as the 3-view seeds:
    # are the near-target tasks lost to what the cameras show, or to acting without lookahead?
    "priv-pool4": str(ROOT / "runs" / "offline" / "priv-pool4" / "policy.pt"),
    # ... and an escape student: regressed on the pool's stalled states only (the tip not
    # nearer its target for 10 steps or more), to act where the seeds stall (`SWITCHED`).
    "3v-escape10": str(ROOT / "runs" / "offline" / "d3-escape10" / "policy.pt"),
    # ... and two fresh students on the first two runs' states of the pool, 24000 steps: the
    # views alone, and the views with their zoomed views (`zoom_pool.py`, `offline.py --zoom`);
    # session 29: one with a collision loss beside the imitation loss (`distill/collisions.py`)
    # and one with a bin head (`distill/bins.py`).
    **{
        f"3v-rows147k-{kind}": str(ROOT / "runs" / "offline" / f"d3-rows147k-{kind}" / "policy.pt")
        for kind in ("base", "zoom", "chunk", "coll", "bins")
    },
    # Session 30: RL fine-tuning from a student (`../finetune/finetune.py`): the privileged
    # student with and without the anchor (the pilot), then the 3-view seeds.
    **{
        f"{student}-ft{tag}": str(ROOT / "runs" / "finetune" / f"{student}{tag}" / "policy.pt")
        for student, tags in (
            ("priv", ("-a0", "-a1", "-a3", "-a10", "-a1-100k", "-a1-100k-n5")),
            *((f"3v-s{s}", ("", "-a10", "-enc")) for s in (5, 7, 8)),
        )
        for tag in tags
    },
}
"""Single students regressed afresh (`distill/offline.py`): on the pooled data of seeds 1 and
2 labelled by the members' mean (`--relabel`) and by the teacher as collected (the control),
and on seed 1's data alone with the teacher's labels (is it the pooling, or the regression?)."""
MEANS = {
    MEAN: tuple(MEMBERS),
    # Session 27: the three seeds of the shipped 3-view recipe (seed 5 is `residual-3views`).
    "3v-mean578": ("3v-s5", "3v-s7", "3v-s8"),
}
"""Mean-action policies (by the names of their members, each in MEMBERS or STUDENTS): the
members act on the same observation, their mean is taken."""
FAMILIES = ("blocked", "obstacles")
COMPARED = {
    **{member: (MEAN,) for member in MEMBERS},
    "distilled": ("pooled",),
    "pooled": ("one-run",),
    "2v-pooled": ("2v-seed0",),
    "1v-pooled": ("1v-seed0",),
    "3v-pool4": ("pooled",),
    "2v-pool5": ("2v-pooled",),
    "1v-pool5": ("1v-pooled",),
    "3v-pool4-48k": ("3v-pool4",),
    "2v-pool5-48k": ("2v-pool5",),
    "1v-pool5-48k": ("1v-pool5",),
    "3v-dagger+2": ("3v-pool4-48k", "seed0"),
    "2v-dagger+2": ("2v-pool5-48k", "2v-seed0"),
    "3v-dagger+4": ("3v-dagger+2",),
    "1v-dagger+2": ("1v-pool5-48k", "1v-seed0"),
    "2v-dagger+4": ("2v-dagger+2",),
    "3v-dagger+2-s6": ("3v-pool4-48k",),
    **{seed: ("3v-mean578",) for seed in ("3v-s5", "3v-s7", "3v-s8")},
    "3v-mean578-distilled": ("3v-mean578", "3v-s5", "3v-s7", "3v-s8"),
    "3v-s5+shield": ("3v-s5",),
    "3v-s5+hybrid": ("3v-s5", "3v-s5+shield"),
    **{name: (policy,) for name, (policy, _) in SWITCHED.items()},
    **{name: (policy,) for name, policy in CROPPED.items()},
    **{name: (policy,) for name, policy in BY_CRITIC.items()},
    **{name: (policy,) for name, (policy, _) in BURST.items()},
    **{name: (policy,) for name, policy in AMPLIFIED.items()},
    **{name: (policy,) for name, (policy, _, _) in LEARNED_SHIELD.items()},
    "3v-rows147k-coll": ("3v-rows147k-base",),
    "3v-rows147k-bins": ("3v-rows147k-base",),
    "3v-rows147k-bins+head": ("3v-rows147k-bins", "3v-rows147k-base"),
    "3v-rows147k-coll+head": ("3v-rows147k-coll", "3v-rows147k-base"),
    "priv-ft-a0": ("priv-pool4",),
    **{f"priv-ft-a{a}": ("priv-pool4",) for a in (1, 3, 10, "1-100k")},
    "priv-ft-a1-100k-n5": ("priv-pool4", "priv-ft-a1-100k"),
    **{f"3v-s{seed}-ft": (f"3v-s{seed}",) for seed in (5, 7, 8)},
    **{f"3v-s{seed}-ft-a10": (f"3v-s{seed}", f"3v-s{seed}-ft") for seed in (5, 7, 8)},
    **{f"3v-s{seed}-ft-enc": (f"3v-s{seed}", f"3v-s{seed}-ft-a10") for seed in (5, 7, 8)},
    **{f"3v-s{seed}+shield": (f"3v-s{seed}",) for seed in (5, 7, 8)},
    **{
        f"3v-s{seed}+shield{variant}": (f"3v-s{seed}+shield", f"3v-s{seed}")
        for seed in (5, 7, 8)
        for variant in (
            "+burst",
            "+burst-half",
            "-unseen+burst",
            *(f"-unseen+burst-{name}" for name in (*ESCAPE_VARIANTS, "free", "open")),
        )
    },
    "3v-near3-s7": ("3v-reg-s7",),
    "3v-near3-s8": ("3v-reg-s8",),
    **{
        name: ("3v-reg-s7", "3v-reg-s8", "3v-reg-s9")
        for name in ("3v-wide32-s7", "3v-reg96k-s7", "3v-nodrop-s7")
    },
    **{
        name: ("3v-reg-s7", "3v-reg-s8", "3v-reg-s9", "3v-reg96k-s7")
        for name in ("3v-pool8-s7", "3v-pool8-s8", "3v-pool7-s7")
    },
    "3v-least4-s7": ("3v-reg-s7", "3v-reg-s8", "3v-reg-s9"),
    "3v-prev4-s7": ("3v-reg-s7", "3v-reg-s8", "3v-reg-s9"),
    "3v-prev4-s8": ("3v-reg-s7", "3v-reg-s8", "3v-reg-s9"),
    **{name: (student,) for name, (student, _) in NEAR_BASE.items()},
    **{
        name: ("3v-prev4-s7", "3v-prev4-s8", "3v-reg-s7", "3v-reg-s8", "3v-reg-s9")
        for name in (
            "3v-tanh-prev4-s7",
            "3v-goal-prev4-s7",
            "3v-goal-prev4-s8",
            "3v-center-prev4-s7",
            "3v-center-prev4-s8",
            "3v-shift8-prev4-s7",
            "3v-shift8-prev4-s8",
            "3v-cos-prev4-s7",
            "3v-cos-prev4-s8",
            "3v-wide32-prev4-s7",
            "3v-wide32-prev4-s8",
            "3v-wd0.1-prev4-s7",
            "3v-wd1-prev4-s7",
            "3v-tip3-prev4-s7",
            "3v-tip3-prev4-s8",
            "3v-ssm-prev4-s7",
            "3v-ssm21-prev4-s7",
        )
    },
    **{
        name: ("3v-s5", "3v-s7", "3v-s8", "3v-s9", "3v-prev4-s7")
        for name in ("3v-prev4-s7-dagger+2", "3v-prev4-s8-dagger+2")
    },
    **{
        name: ("3v-s5", "3v-s7", "3v-s8", "3v-s9", "3v-prev4-s7", "3v-prev4-s7-dagger+2")
        for name in ("3v-prev4-s7-dart+2", "3v-prev4-s8-dart+2")
    },
}
"""Who each policy is compared with task by task in the summary, where both ran on the block."""


NAMES = (
    *MEMBERS,
    *MEANS,
    *STUDENTS,
    *GUARDED,
    *SHIELDED_BURST,
    *SWITCHED,
    *CROPPED,
    *BY_CRITIC,
    *HEADED,
    *BURST,
    *AMPLIFIED,
    *LEARNED_SHIELD,
    *NEAR_BASE,
)
"""Every policy by name, in the summary's order."""


class MeanActionPolicy:
    """The average of several policies' actions (each deterministic), one call each per step."""

    def __init__(self, members: list) -> None:
        self.members = members

    def reset(self, env=None) -> None:
        for member in self.members:
            member.reset(env)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return np.mean([member.act(obs) for member in self.members], axis=0)


class CropMeanPolicy:
    """A student's mean action over fixed crops of its views (test-time augmentation with the
    training's crops): the tanh of the mean of its pre-squash means, all crops in one batch."""

    def __init__(self, agent, offsets=CROP_OFFSETS) -> None:
        self.agent = agent
        self.offsets = offsets

    def reset(self, env=None) -> None:
        pass

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        import torch

        size = self.agent.config.encoder.image_size
        images = np.asarray(obs["images"])
        batch = {k: np.repeat(np.asarray(v)[None], len(self.offsets), 0) for k, v in obs.items()}
        batch["images"] = np.stack(
            [images[..., top : top + size, left : left + size] for top, left in self.offsets]
        )
        with torch.inference_mode():
            return np.tanh(self.agent.mean_action(batch).mean(0))


class NearTargetBase:
    """A residual student acting with its base alone (the tanh of the stage-1 joint policy's
    mean, which the residual is added to) while the tip is within `radius_m` of the target,
    as itself farther out. No geometry is read: the distance is the observation's goal minus
    its achieved goal."""

    def __init__(self, policy, radius_m: float) -> None:
        self.policy, self.agent, self.radius_m = policy, policy.agent, radius_m

    def reset(self, env=None) -> None:
        self.policy.reset(env)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        import torch

        if np.linalg.norm(obs["achieved_goal"] - obs["desired_goal"]) >= self.radius_m:
            return self.policy.act(obs)
        batch = {k: np.asarray(v)[None] for k, v in obs.items()}
        with torch.inference_mode():
            low_dim = self.agent._actor_view(self.agent.low_dim_input(batch))
            return np.tanh(self.agent._base_mean(low_dim)[0].cpu().numpy())


class EscapeChooser:
    """Session 31, third round: a burst's command among `CANDIDATES` random ones (each joint
    uniform in [-1, 1]) by the shield's map (`DepthClearance`): each candidate's path is its
    command repeated `BURST_STEPS` steps from the present joints (joint limits applied), and
    its score the least clearance along it to the obstacle surface seen so far and the table
    (capped at `OPEN_CAP_M`). `mode` "free": the first candidate whose path keeps the shield's
    margin (else the best scored), so that an escape is not one the shield would stop; "open":
    the best scored, the way into the most open space."""

    CANDIDATES = 16
    OPEN_CAP_M = 0.15

    def __init__(self, checker, mode: str) -> None:
        self.checker, self.mode = checker, mode

    def __call__(self, rng: np.random.Generator, obs: dict) -> np.ndarray:
        from clamgen.envs.reach_env import step_target
        from clamgen.experiments.stall import BURST_STEPS

        commands = rng.uniform(-1.0, 1.0, (self.CANDIDATES, 6))
        joints = np.asarray(obs["observation"], np.float64)[:6]
        paths = np.empty((self.CANDIDATES, BURST_STEPS, 6))
        for k, command in enumerate(commands):
            at = joints
            for step in range(BURST_STEPS):
                at = paths[k, step] = step_target(at, command)
        arm, points = self.checker.arm, self.checker.points
        cap = self.OPEN_CAP_M
        score = arm.clearances(paths.reshape(-1, 6), points, cap).reshape(self.CANDIDATES, -1)
        score = score.min(axis=1)
        if self.mode == "free":
            free = np.flatnonzero(score >= self.checker.margin_m)
            return commands[free[0] if len(free) else int(np.argmax(score))]
        return commands[int(np.argmax(score))]


class SaturatedPolicy:
    """A policy's command scaled (direction kept) until its largest joint command is 1."""

    def __init__(self, policy) -> None:
        self.policy = policy

    def reset(self, env=None) -> None:
        self.policy.reset(env)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        action = np.asarray(self.policy.act(obs))
        return action / max(float(np.abs(action).max()), 1e-6)


def done(out: Path = OUT) -> list[dict]:
    if not out.exists():
        return []
    return [json.loads(line) for line in out.read_text().splitlines() if line]


def load(name: str):
    from clamgen.experiments.policies import load_policy

    if name in GUARDED or name in SHIELDED_BURST:
        from clamgen.experiments.depth_planner import HYBRID
        from clamgen.experiments.stall import StallBurst

        if name in GUARDED:
            (base, planner), options, changes, mode = GUARDED[name], None, {}, None
        else:
            (base, options, changes, mode), planner = SHIELDED_BURST[name], False
        policy, kwargs = load(base)
        if options is not None:
            policy = StallBurst(policy, **options)
        guard = dataclasses.replace(HYBRID[kwargs["num_views"]], planner=planner, **changes)
        shielded, kwargs = guard.around(policy, kwargs)
        if mode is not None:
            policy.choose = EscapeChooser(shielded.checker, mode)
        return shielded, kwargs
    if name in HEADED:
        import importlib
        import sys

        student, module, policy_class = HEADED[name]
        sys.path.insert(0, str(HERE.parent / "distill"))
        module = importlib.import_module(module)
        policy, kwargs = load(student)
        head = Path(STUDENTS[student]).parent / module.HEAD_NAME
        return getattr(module, policy_class)(policy.agent, head), kwargs
    if name in BY_CRITIC:
        from clamgen.agents.residual import CRITIC_CANDIDATES
        from clamgen.experiments.evaluate import SACPolicy

        policy, kwargs = load(BY_CRITIC[name])
        return SACPolicy(policy.agent, critic_candidates=CRITIC_CANDIDATES), kwargs
    if name in CROPPED:
        policy, kwargs = load(CROPPED[name])
        return CropMeanPolicy(policy.agent), kwargs
    if name in LEARNED_SHIELD:
        from clamgen.experiments.learned_shield import HEAD_NAME, LearnedShieldPolicy

        base, directory, threshold = LEARNED_SHIELD[name]
        policy, kwargs = load(base)
        return LearnedShieldPolicy(policy.agent, directory / HEAD_NAME, float(threshold)), kwargs
    if name in BURST:
        from clamgen.experiments.stall import StallBurst

        base, options = BURST[name]
        policy, kwargs = load(base)
        return StallBurst(policy, **options), kwargs
    if name in NEAR_BASE:
        student, radius_m = NEAR_BASE[name]
        policy, kwargs = load(student)
        return NearTargetBase(policy, radius_m), kwargs
    if name in AMPLIFIED:
        from clamgen.experiments.stall import StallSwitch

        policy, kwargs = load(AMPLIFIED[name])
        return StallSwitch(policy, SaturatedPolicy(policy)), kwargs
    if name in SWITCHED:
        from clamgen.experiments.stall import StallSwitch

        (policy, kwargs), (escape, escape_kwargs) = (load(part) for part in SWITCHED[name])
        if escape_kwargs != kwargs:
            raise SystemExit("the policy and its escape observe with different env options")
        return StallSwitch(policy, escape), kwargs
    if name not in MEANS:
        policy, _, kwargs = load_policy({**MEMBERS, **STUDENTS}[name])
        return policy, kwargs
    loaded = [load_policy({**MEMBERS, **STUDENTS}[member]) for member in MEANS[name]]
    kwargs = loaded[0][2]
    if any(other[2] != kwargs for other in loaded[1:]):
        raise SystemExit("the members observe with different env options")
    return MeanActionPolicy([policy for policy, _, _ in loaded]), kwargs


def run(name: str, family: str, seeds: list[int]) -> dict:
    import torch

    from clamgen.envs import ReachEnv
    from clamgen.experiments.evaluate import evaluate, per_task
    from clamgen.experiments.machine import describe

    torch.set_num_threads(1)
    policy, kwargs = load(name)
    env = ReachEnv(num_obstacles=2, task_family=family, **kwargs)
    records = evaluate(env, policy, seeds)
    env.close()
    return (
        {"policy": name, "family": family, "seeds": seeds}
        | per_task(records)
        | {"machine": describe()}
    )


def summary(lines: list[dict]) -> None:
    from clamgen.experiments.tables import paired_count, wilson_interval

    def rate(values: list[bool]) -> str:
        k, n = int(np.sum(values)), len(values)
        low, high = wilson_interval(k, n)
        return f"{k / n:.3f} ({low:.3f}-{high:.3f})"

    by = {(x["policy"], x["family"]): x for x in lines}
    for family in FAMILIES:
        for name in NAMES:
            line = by.get((name, family))
            if line is None:
                continue
            text = (
                f"{family:9s} {name:12s} ({len(line['seeds'])} tasks): success "
                f"{rate(line['success'])}, collisions {rate(line['collided'])}, "
                f"act {line['act_median_ms']:.2f} ms"
            )
            for other in COMPARED.get(name, ()):
                if (other, family) not in by:
                    continue
                count = paired_count(line["success"], by[other, family]["success"])
                text += (
                    f"; {other} solves {count.second_only} it fails, fails {count.first_only} "
                    f"it solves (P = {count.p_value:.3f})"
                )
            print(text)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-blocked", type=int, default=300)
    parser.add_argument("--num-standard", type=int, default=100)
    parser.add_argument("--offset", type=int, default=70_000)
    parser.add_argument(
        "--policies",
        nargs="+",
        choices=NAMES,
        default=[*MEMBERS, MEAN],
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=OUT,
        help="the JSON-lines file (one per block of tasks); a bare file name lies beside this "
        "script, as the README's commands expect, wherever it is run from",
    )
    parser.add_argument("--summary", action="store_true", help="only print the comparison")
    args = parser.parse_args()
    if args.out.parent == Path("."):
        args.out = HERE / args.out
    if not args.summary:
        from clamgen.experiments.config import VALIDATION_SEEDS

        first = VALIDATION_SEEDS.start + args.offset
        counts = {"blocked": args.num_blocked, "obstacles": args.num_standard}
        for name in args.policies:
            for family, count in counts.items():
                seeds = [int(s) for s in VALIDATION_SEEDS.seeds(count, first)]
                there = [x for x in done(args.out) if (x["policy"], x["family"]) == (name, family)]
                if there and there[0]["seeds"] != seeds:
                    raise SystemExit(f"{args.out} holds other tasks for {name}: give another --out")
                if there:
                    continue
                line = run(name, family, seeds)
                with args.out.open("a") as f:
                    f.write(json.dumps(line) + "\n")
                print(f"{name} {family}: success {np.mean(line['success']):.3f}", flush=True)
    summary(done(args.out))


if __name__ == "__main__":
    main()
