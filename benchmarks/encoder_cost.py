"""Cost of the stage-2 multi-view encoder on this machine: forward, forward + backward, and the
SAC+CURL update it implies, for a grid of views / image size / strides / batch / weight sharing.

    python benchmarks/encoder_cost.py [--sizes 84 64] [--strides 2,1,1,1 2,2,1,1]
        [--batches 128 256] [--views 3] [--channels 32] [--repeats 2] [--threads 2] [--bf16]
        [--conv-chunk 32] [--no-csv]

The reference is the paper-like encoder (first size, first strides, shared weights) at the same
batch, measured in the same run; "speedup" is its forward + backward time over each row's.
Update estimates (the actor / critic MLPs cost little next to the convs and are left out):

- curl: CURL's own recipe, 2 forward + backward (critic; CURL query) and 3 forward passes
  (target critic on s'; actor on detached conv features; momentum key encoder).
- lean: 1 forward + backward (critic, CURL, across-view and collision losses summed on one
  online pass, the actor reusing its detached features) and 2 forward (target on s', key).

On a machine shared with another training job use --threads 1: two OpenMP threads competing
with the job for 2 cores measured 2-5x slower than one thread (64 px, batch 128).

Writes results/benchmarks/encoder_cost.csv unless --no-csv.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import write_csv

from clamgen.agents.encoders import EncoderConfig, MultiViewEncoder

BUDGET_S = 2 * 3600.0
"""Wall-clock budget the 'updates in 2 h' columns divide."""


def best_seconds(fn, repeats: int, budget_s: float = 1.5) -> float:
    """Best wall time of ``fn()`` over up to ``repeats`` runs; after the first run, stops
    early once ``budget_s`` is spent (long runs are less noisy and dominate the total)."""
    best = float("inf")
    spent = 0.0
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        fn()
        elapsed = time.perf_counter() - start
        best, spent = min(best, elapsed), spent + elapsed
        if spent > budget_s:
            break
    return best


def time_encoder(
    config: EncoderConfig, batch: int, repeats: int, bf16: bool = False
) -> dict[str, float]:
    """Forward (no grad) and forward + backward times in ms, and the parameter count.

    With ``bf16`` the passes run under CPU autocast to bfloat16 (convs and matmuls in bf16,
    LayerNorm and the loss in float32), which oneDNN runs natively on CPUs with AVX512-BF16/AMX.
    """
    torch.manual_seed(0)
    encoder = MultiViewEncoder(config)
    shape = (batch, config.num_views, config.in_channels, config.image_size, config.image_size)
    images = torch.randint(0, 256, shape, dtype=torch.uint8)
    autocast = torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16)

    def forward() -> None:
        with torch.no_grad(), autocast:
            encoder(images)

    def forward_backward() -> None:
        encoder.zero_grad(set_to_none=True)
        with autocast:
            encoding = encoder(images)
        encoding.float().square().mean().backward()

    forward_backward()  # warm-up: allocator, oneDNN primitive caches
    return {
        "fwd_bwd_ms": 1e3 * best_seconds(forward_backward, repeats),
        "fwd_ms": 1e3 * best_seconds(forward, repeats),
        "params_m": sum(p.numel() for p in encoder.parameters()) / 1e6,
    }


def parse_strides(text: str) -> tuple[int, ...]:
    return tuple(int(s) for s in text.split(","))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=3)
    parser.add_argument("--sizes", type=int, nargs="+", default=[84, 64])
    parser.add_argument("--strides", type=parse_strides, nargs="+", default=["2,1,1,1", "2,2,1,1"])
    parser.add_argument("--batches", type=int, nargs="+", default=[128, 256])
    parser.add_argument("--channels", type=int, default=32)
    parser.add_argument("--shared", choices=["both", "yes", "no"], default="both")
    parser.add_argument("--repeats", type=int, default=2, help="timed runs per cell (best of)")
    parser.add_argument("--bf16", action="store_true", help="autocast to bfloat16 (CPU)")
    parser.add_argument(
        "--conv-chunk", type=int, default=32, help="EncoderConfig.cpu_conv_chunk; 0 = one call"
    )
    parser.add_argument("--threads", type=int, default=torch.get_num_threads())
    parser.add_argument("--no-csv", action="store_true")
    args = parser.parse_args()
    # argparse applies `type` to string defaults only.
    strides_list = [parse_strides(s) if isinstance(s, str) else s for s in args.strides]
    shared_options = {"both": [True, False], "yes": [True], "no": [False]}[args.shared]
    torch.set_num_threads(args.threads)
    print(
        f"torch {torch.__version__}, {args.threads} threads, {os.cpu_count()} CPUs, "
        f"{'bfloat16 autocast' if args.bf16 else 'float32'}, channels {args.channels}, "
        f"conv chunk {args.conv_chunk or 'none'}, "
        f"load average {os.getloadavg()[0]:.2f} at start"
    )

    header = (
        f"{'V':>2} {'px':>3} {'strides':>9} {'batch':>5} {'shared':>6} {'params_M':>8} "
        f"{'fwd_ms':>7} {'fb_ms':>7} {'us/img':>6} {'speedup':>7} {'curl_ms':>7} "
        f"{'lean_ms':>7} {'curl_2h':>7} {'lean_2h':>7}"
    )
    print(header)
    rows: list[dict] = []
    start = time.perf_counter()
    for batch in args.batches:
        reference_ms = None
        for size in args.sizes:
            for strides in strides_list:
                for shared in shared_options:
                    config = EncoderConfig(
                        image_size=size,
                        num_views=args.views,
                        num_channels=args.channels,
                        strides=strides,
                        share_view_weights=shared,
                        cpu_conv_chunk=args.conv_chunk or None,
                    )
                    cost = time_encoder(config, batch, args.repeats, args.bf16)
                    if reference_ms is None:
                        reference_ms = cost["fwd_bwd_ms"]
                    curl_ms = 2 * cost["fwd_bwd_ms"] + 3 * cost["fwd_ms"]
                    lean_ms = cost["fwd_bwd_ms"] + 2 * cost["fwd_ms"]
                    row = {
                        "views": args.views,
                        "image_px": size,
                        "strides": "-".join(map(str, strides)),
                        "batch": batch,
                        "shared": shared,
                        "channels": args.channels,
                        "params_m": round(cost["params_m"], 2),
                        "fwd_ms": round(cost["fwd_ms"], 1),
                        "fwd_bwd_ms": round(cost["fwd_bwd_ms"], 1),
                        "fwd_bwd_us_per_image": round(
                            1e3 * cost["fwd_bwd_ms"] / (batch * args.views), 1
                        ),
                        "speedup_vs_reference": round(reference_ms / cost["fwd_bwd_ms"], 2),
                        "curl_update_ms": round(curl_ms, 1),
                        "lean_update_ms": round(lean_ms, 1),
                        "curl_updates_in_2h": int(BUDGET_S / (curl_ms / 1e3)),
                        "lean_updates_in_2h": int(BUDGET_S / (lean_ms / 1e3)),
                        "threads": args.threads,
                        "precision": "bf16" if args.bf16 else "fp32",
                        "conv_chunk": args.conv_chunk,
                    }
                    rows.append(row)
                    print(
                        f"{args.views:>2} {size:>3} {row['strides']:>9} {batch:>5} "
                        f"{shared!s:>6} {row['params_m']:>8.2f} {row['fwd_ms']:>7.1f} "
                        f"{row['fwd_bwd_ms']:>7.1f} {row['fwd_bwd_us_per_image']:>6.0f} "
                        f"{row['speedup_vs_reference']:>6.2f}x {curl_ms:>7.0f} {lean_ms:>7.0f} "
                        f"{row['curl_updates_in_2h']:>7} {row['lean_updates_in_2h']:>7}",
                        flush=True,
                    )
    print(
        f"total {time.perf_counter() - start:.0f} s, load average {os.getloadavg()[0]:.2f} at end"
    )
    if not args.no_csv:
        print(f"wrote {write_csv('encoder_cost', rows)}")


if __name__ == "__main__":
    main()
