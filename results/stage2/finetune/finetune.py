"""RL fine-tuning of a distilled student (beyond the paper): SAC starts from the student.

    python results/stage2/finetune/finetune.py results/stage2/ensemble/3v-dagger+2_policy.pt \
        runs/finetune/3v-s5 --steps 30000 --anchor 10

The distilled students imitate a privileged teacher and stay a few tasks of 300 from where
they start whatever the imitation lever (`../ensemble/README.md`, the ledger); what they never
see is their own reward. Here stage 2's RL loop (`clamgen train-residual`) starts from a
student's networks instead of fresh ones (`Stage2Config.init_policy`), on the task mix the
student was distilled on:

- the student's encoder stays frozen (`agent.freeze_encoder`): RL adjusts the controller on the
  features imitation taught, and an update skips the convs' backward pass (`--train-encoder`:
  trained by the critic and the student's own auxiliary losses, as in stage 2);
- the first `--critic-first` updates train the critic alone (`agent.critic_first_updates`): a
  fresh Q_res is 0, and the actor's first gradients would otherwise come from Q_base alone,
  which knows nothing of the obstacles;
- `--anchor` (`agent.anchor_weight`) pulls the actor's mean towards the student's own where
  the critic has nothing better;
- a collision ends a training episode with a penalty of `--penalty` (`env.collision_ends_
  episode`, a constant `env.collision_penalty`): evaluation counts a collided episode as
  failed, and the penalty is set above the discounted cost of stalling to the time limit
  (0.01 / (1 - 0.98) = 0.5), so that a collision is never the cheaper way out;
- no hindsight relabelling (`image_her` off): the student reaches most targets already, and
  re-rendering would take a third process on two cores.

Everything else (views, image size, network sizes, base policy) is the student's own config.
The run directory holds the config, metrics and checkpoints like any `train-residual` run;
running the same command again resumes it. The policy file (`policy.pt`) is the last step's.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from clamgen.agents.aux_losses import AuxLossConfig
from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.config import config_from_json
from clamgen.experiments.stage2 import RESIDUAL_POLICY_KIND, Stage2Config, Stage2Trainer
from clamgen.schedules import Constant

# The discounted cost of stalling to the time limit is 0.01 / (1 - gamma) = 0.5 at gamma 0.98;
# a collision that ends the episode must cost more, or it is the cheaper way out.
COLLISION_PENALTY = 1.0
FROZEN_AUX = AuxLossConfig(curl_weight=0.0, across_view_weight=0.0, collision_weight=0.0)


def finetune_config(student: Path, run_dir: Path, args: argparse.Namespace) -> Stage2Config:
    """The student's own config with the fine-tuning settings of `args`."""
    payload = ckpt.load_torch(student, RESIDUAL_POLICY_KIND)
    config: Stage2Config = config_from_json(payload["config"], Stage2Config)
    env = dataclasses.replace(
        config.env,
        num_envs=2,
        collision_ends_episode=args.collision_ends,
        collision_penalty=Constant(args.penalty),
    )
    agent = dataclasses.replace(
        config.agent,
        warmup_updates=0,
        freeze_encoder=not args.train_encoder,
        critic_first_updates=args.critic_first,
        anchor_weight=args.anchor,
        actor_lr=args.actor_lr,
        # A frozen encoder: losses that only shape it would cost updates for nothing. A trained
        # one keeps the student's own auxiliary losses (stage 2's).
        aux=config.agent.aux if args.train_encoder else FROZEN_AUX,
    )
    replay = dataclasses.replace(
        config.replay, capacity=min(args.steps, 100_000), n_step=args.n_step
    )
    loop = dataclasses.replace(
        config.loop,
        total_env_steps=args.steps,
        learning_starts=args.learning_starts,
        updates_per_step=0.5,
        eval_every_steps=args.eval_every,
        num_eval_episodes=args.eval_episodes,
        checkpoint_every_steps=args.eval_every,
        seed=args.seed,
        torch_threads=1,
        teacher_fraction=0.0,
    )
    return dataclasses.replace(
        config,
        run_dir=run_dir,
        init_policy=str(student),
        image_her=False,
        env=env,
        agent=agent,
        replay=replay,
        loop=loop,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("student", type=Path, help="the residual policy file to start from")
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--steps", type=int, default=30_000, help="environment steps")
    parser.add_argument("--anchor", type=float, default=0.0, help="agent.anchor_weight")
    parser.add_argument("--critic-first", type=int, default=2_000, help="critic-only updates")
    parser.add_argument("--actor-lr", type=float, default=1e-4)
    parser.add_argument("--penalty", type=float, default=COLLISION_PENALTY)
    parser.add_argument(
        "--collision-ends",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="a collision ends a training episode (env.collision_ends_episode)",
    )
    parser.add_argument("--n-step", type=int, default=1, help="replay.n_step (returns)")
    parser.add_argument(
        "--train-encoder",
        action="store_true",
        help="train the student's encoder too (by the critic and its own auxiliary losses)",
    )
    parser.add_argument("--learning-starts", type=int, default=1_000)
    parser.add_argument("--eval-every", type=int, default=5_000)
    parser.add_argument("--eval-episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    try:
        config = finetune_config(args.student, args.run_dir, args)
    except (ckpt.CheckpointError, ValueError) as error:
        raise SystemExit(f"error: {error}") from None
    Stage2Trainer(config).run()


if __name__ == "__main__":
    main()
