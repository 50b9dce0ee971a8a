"""Benchmark: touch2robot.metrics.contact_scores vs scikit-learn's confusion_matrix.

    uv run python bench/metrics.py [--pairs 1e8] [--regions 8] [--repeat 3] [--seed 0]

Both run in the same process on the same bool arrays of ``--pairs`` time-region pairs, shaped
(pairs / regions, regions). contact_scores gets the (time, region) arrays as they are;
scikit-learn gets the flattened views with labels=[False, True]. Times are the best of
``--repeat`` runs for contact_scores and a single run for scikit-learn (about 20 s and ~2 GB
peak RSS for the whole process at 1e8; use a smaller --pairs on small machines). The
per-region breakdown (``per_region=True``) is timed too, for information.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from sklearn.metrics import confusion_matrix

from touch2robot.metrics import contact_scores

# Generate in slices so no float64 temporaries of full size are created.
_GEN_CHUNK = 1 << 24


def make_data(n_pairs: int, n_regions: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Reference contact ~30 % on; evaluated disagrees on ~10 % of pairs."""
    rng = np.random.default_rng(seed)
    n_rows = n_pairs // n_regions
    ref = np.empty(n_rows * n_regions, dtype=bool)
    ev = np.empty_like(ref)
    for start in range(0, ref.size, _GEN_CHUNK):
        n = min(_GEN_CHUNK, ref.size - start)
        u = rng.integers(0, 100, size=n, dtype=np.uint8)
        ref[start : start + n] = u < 30
        flip = rng.integers(0, 10, size=n, dtype=np.uint8) == 0
        np.not_equal(ref[start : start + n], flip, out=ev[start : start + n])
    return ref.reshape(n_rows, n_regions), ev.reshape(n_rows, n_regions)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pairs", type=float, default=1e8, help="time-region pairs (default 1e8)")
    parser.add_argument("--regions", type=int, default=8)
    parser.add_argument("--repeat", type=int, default=3, help="contact_scores repetitions (best kept)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    ref, ev = make_data(int(args.pairs), args.regions, args.seed)
    print(f"pairs: {ref.size:,} ({ref.shape[0]:,} samples x {ref.shape[1]} regions), bool arrays")

    ours_s = float("inf")
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        ours = contact_scores(ref, ev)
        ours_s = min(ours_s, time.perf_counter() - t0)

    by_region_s = float("inf")
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        by_region = contact_scores(ref, ev, regions=[f"R{k}" for k in range(args.regions)], per_region=True)
        by_region_s = min(by_region_s, time.perf_counter() - t0)

    t0 = time.perf_counter()
    tn, fp, fn, tp = confusion_matrix(ref.ravel(), ev.ravel(), labels=[False, True]).ravel()
    sk_s = time.perf_counter() - t0

    same = (ours.tp, ours.fp, ours.fn, ours.tn) == (int(tp), int(fp), int(fn), int(tn))
    same = same and by_region.overall == ours
    print(f"contact_scores:           {ours_s * 1e3:10.1f} ms  (best of {args.repeat})")
    print(f"  with per_region=True:   {by_region_s * 1e3:10.1f} ms  (best of {args.repeat})")
    print(f"sklearn confusion_matrix: {sk_s * 1e3:10.1f} ms")
    print(f"speed-up: {sk_s / ours_s:.1f}x")
    print(f"counts identical: {same}  (tp={ours.tp:,} fp={ours.fp:,} fn={ours.fn:,} tn={ours.tn:,})")
    print(f"precision={ours.precision:.6f} recall={ours.recall:.6f} f1={ours.f1:.6f} fpr={ours.fpr:.6f}")
    if not same:
        raise SystemExit("counts differ from scikit-learn")


if __name__ == "__main__":
    main()
