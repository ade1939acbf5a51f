"""Pictures of the gate: SSIM over time, and input vs re-render vs SSIM map for a few frames."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np


def write_report(
    report_dir: Path, ssim: np.ndarray, threshold: float, samples: dict[int, tuple], verdict: str = ""
) -> None:
    """``ssim.csv``, ``ssim.png`` and ``compare.png``, both pictures titled with ``verdict`` (the
    gate's PASS or FAIL and what failed: the pictures alone looked all-pass on a gate that failed
    its rest check)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.arange(len(ssim))
    ok = np.isfinite(ssim)
    np.savetxt(
        report_dir / "ssim.csv",
        np.stack([t[ok], ssim[ok]], axis=1),
        delimiter=",",
        header="frame,ssim",
        comments="",
        fmt=["%d", "%.6f"],
    )

    fig, ax = plt.subplots(figsize=(7, 2.6), dpi=120)
    ax.plot(t[ok], ssim[ok], lw=1.5, label=f"SSIM (mean {np.nanmean(ssim):.3f})")
    ax.axhline(threshold, color="tab:red", ls="--", lw=1, label=f"threshold {threshold:.2f}")
    ax.set_xlabel("frame")
    ax.set_ylabel("SSIM")
    ax.set_ylim(max(0.0, min(threshold, np.nanmin(ssim)) - 0.05), 1.0)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left", fontsize=8)
    if verdict:
        ax.set_title(textwrap.fill(verdict, 110), fontsize=7, loc="left")
    fig.tight_layout()
    fig.savefig(report_dir / "ssim.png")
    plt.close(fig)

    frames = sorted(samples)
    cmap = plt.get_cmap("viridis").with_extremes(bad="0.6")  # gray: excluded pixels (the interactor)
    fig, axes = plt.subplots(
        len(frames), 3, figsize=(10, 2.5 * len(frames)), dpi=100, squeeze=False, layout="constrained"
    )
    for row, frame in zip(axes, frames):
        original, rendered, ssim_map, exclude = samples[frame]
        shown = np.ma.masked_where(exclude, ssim_map) if exclude is not None else ssim_map
        row[0].imshow(original)
        row[0].set_title(f"input, frame {frame}", fontsize=8)
        row[1].imshow(rendered)
        row[1].set_title("re-render (Mitsuba, from the stage)", fontsize=8)
        im = row[2].imshow(shown, vmin=0.0, vmax=1.0, cmap=cmap)
        row[2].set_title(f"SSIM map, mean {ssim[frame]:.3f} (gray: excluded)", fontsize=8)
        for ax in row:
            ax.axis("off")
    fig.colorbar(im, ax=axes[:, 2].tolist(), shrink=0.5, label="SSIM")
    if verdict:
        fig.suptitle(textwrap.fill(verdict, 150), fontsize=9)
    fig.savefig(report_dir / "compare.png")
    plt.close(fig)
