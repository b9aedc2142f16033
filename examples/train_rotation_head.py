"""Which rotation representation should a network output? A small CPU reproduction of Zhou et al. 2019.

Zhou, Barnes, Lu, Yang and Li, "On the Continuity of Rotation Representations in Neural
Networks" (CVPR 2019), train one network per representation to predict the rotation between a
point cloud and its rotated copy, and find the continuous 6D (and, in Levinson et al. 2020, 9D
with SVD) far more accurate than quaternions, axis-angle and Euler angles, whose worst cases
are near 180 degrees.

Here: one fixed random point cloud ``P`` (``--points`` points), targets drawn uniformly from
SO(3) (fresh every step, as in the paper), an MLP on the flattened pair ``(P, R P)`` and a
:class:`torchquat.nn.RotationHead` per representation. Every head gets the same network,
seed, data stream, optimiser, step budget and loss (:class:`torchquat.nn.ChordalLoss`, the L2
loss on matrices). Errors are geodesic angles (degrees) on held-out uniform rotations.
Differences from the paper: one fixed random cloud instead of ShapeNet airplanes, an MLP
instead of a PointNet, and a far smaller budget, so absolute numbers differ; compare the
ranking. With a fixed cloud, R is a linear function of the input (``R = (R P) P^+``), so a
continuous head can fit it almost exactly; what remains for the 3D and 4D heads is their
discontinuity, which shows as maximum errors near 180 degrees.

Run::

    python examples/train_rotation_head.py            # a few minutes on 2 cores
    python examples/train_rotation_head.py --quick    # seconds: a smoke test
    python examples/train_rotation_head.py --out docs # the copy shown in the README

Writes ``train_rotation_head.md`` (the table) and ``train_rotation_head.png`` (error CDF) to
``--out`` and prints the table.
"""

import argparse
import os
import sys
import time

import torch
from torch import nn

import torchquat
from torchquat.nn import ChordalLoss, RotationHead

HEADS = (  # (label, representation, convention)
    ("quat", "quat", None),
    ("euler (ZYX)", "euler", "ZYX"),
    ("axis_angle", "axis_angle", None),
    ("rot6d", "rot6d", None),
    ("rot9d", "rot9d", None),
)


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="tiny budget: a smoke test that finishes in seconds")
    p.add_argument("--out", default=os.path.join("examples", "output"), help="folder for the table and the plot")
    p.add_argument("--steps", type=int, default=None, help="training steps per head (default 4000, quick 60)")
    p.add_argument("--batch", type=int, default=None, help="batch size (default 128, quick 64)")
    p.add_argument("--points", type=int, default=32, help="points in the cloud")
    p.add_argument("--width", type=int, default=None, help="hidden width (default 256, quick 64)")
    p.add_argument("--test", type=int, default=None, help="held-out rotations (default 10000, quick 1000)")
    p.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate (divided by 10 for the last quarter)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None,
                   help="torch.set_num_threads (default 1: the layers are small, and one thread is not "
                        "slowed down by other busy processes)")
    args = p.parse_args(argv)
    quick = args.quick
    args.steps = args.steps or (60 if quick else 4000)
    args.batch = args.batch or (64 if quick else 128)
    args.width = args.width or (64 if quick else 256)
    args.test = args.test or (1000 if quick else 10000)
    return args


def make_net(n_points: int, width: int, representation: str, convention) -> nn.Module:
    return nn.Sequential(
        nn.Flatten(-2),  # (B, 2N, 3) -> (B, 6N): the pair (P, R P), flattened
        nn.Linear(6 * n_points, width), nn.ReLU(),
        nn.Linear(width, width), nn.ReLU(),
        nn.Linear(width, width), nn.ReLU(),
        RotationHead(width, representation, convention=convention),
    )


def batch_of(cloud: torch.Tensor, n: int, generator: torch.Generator):
    """Uniform random rotations and the network input ``cat(P, R P)`` for each."""
    R = torchquat.quat_to_matrix(torchquat.random_quat(n, generator=generator))
    rotated = cloud @ R.mT  # (B, N, 3): each point p becomes R p
    return torch.cat((cloud.expand_as(rotated), rotated), dim=-2), R


def train_one(args, cloud, representation, convention, test_x, test_R):
    torch.manual_seed(args.seed)  # same initial weights (up to the head's size) for every head
    net = make_net(args.points, args.width, representation, convention)
    data = torch.Generator().manual_seed(args.seed + 1)  # same training stream for every head
    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    sched = torch.optim.lr_scheduler.MultiStepLR(opt, milestones=[(3 * args.steps) // 4], gamma=0.1)
    loss_fn = ChordalLoss()
    for _ in range(args.steps):
        x, R = batch_of(cloud, args.batch, data)
        loss = loss_fn(net(x), R)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
    net.eval()
    with torch.no_grad():
        pred = torch.cat([net(chunk) for chunk in test_x.split(2048)])
    return torch.rad2deg(torchquat.matrix_geodesic_distance(pred, test_R))


def table(results) -> str:
    lines = ["| head | mean (deg) | median (deg) | max (deg) |", "|---|---:|---:|---:|"]
    for label, err in results.items():
        lines.append(f"| {label} | {err.mean():.2f} | {err.median():.2f} | {err.max():.2f} |")
    return "\n".join(lines)


def plot(results, path: str, title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=110)
    for label, err in results.items():
        e = err.sort().values.numpy()
        ax.plot(e, [(i + 1) / len(e) for i in range(len(e))], label=label, lw=1.6)
    ax.set_xscale("log")
    ax.set_xlabel("geodesic error (degrees, log scale)")
    ax.set_ylabel("fraction of held-out rotations")
    ax.set_ylim(0, 1.0)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="lower right")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv=None) -> int:
    args = parse_args(argv)
    torch.set_num_threads(args.threads or 1)
    start = time.perf_counter()
    g = torch.Generator().manual_seed(args.seed)
    cloud = torch.randn(args.points, 3, generator=g)  # fixed, asymmetric (almost surely)
    cloud = cloud - cloud.mean(0)
    test_x, test_R = batch_of(cloud, args.test, torch.Generator().manual_seed(args.seed + 12345))

    results = {}
    for label, representation, convention in HEADS:
        t0 = time.perf_counter()
        results[label] = train_one(args, cloud, representation, convention, test_x, test_R)
        print(f"{label:>12}: {time.perf_counter() - t0:6.1f} s, mean error {results[label].mean():.2f} deg",
              file=sys.stderr)

    wall = time.perf_counter() - start
    setup = (f"{args.steps} steps x batch {args.batch}, MLP width {args.width}, {args.points} points, "
             f"ChordalLoss, Adam lr {args.lr:g}, seed {args.seed}; {args.test} held-out uniform rotations; "
             f"{wall:.0f} s on {torch.get_num_threads()} CPU thread(s)")
    text = table(results)
    print(text)
    print(f"\n{setup}")
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "train_rotation_head.md"), "w") as f:
        f.write(f"Geodesic error on held-out rotations ({setup}).\n\n{text}\n")
    plot(results, os.path.join(args.out, "train_rotation_head.png"),
         f"Error CDF per head ({args.steps} steps x {args.batch}, seed {args.seed})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
