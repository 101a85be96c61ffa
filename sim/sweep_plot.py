"""Plot of a sweep: pass/fail and worst margin per variant (matplotlib, Agg)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trajgen.gimbal import JOINT_NAMES


def plot_sweep(results, path, joint_names=JOINT_NAMES) -> Path:
    """One panel per (payload offset, servo set); payload across, time scale down.

    Each cell is coloured by the worst planned margin (N m; red below zero) and
    marked "ok" or "FAIL" with the failed parts; failing cells are hatched in red
    (a variant can fail on tracking with plenty of torque margin).

    Parameters
    ----------
    results : sequence of VariantResult
    path : str or Path
        PNG to write.
    joint_names : tuple of str
        The gimbal's joints, base out (a panel names their servos).

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import TwoSlopeNorm
    from matplotlib.patches import Rectangle

    path = Path(path)
    panels = list(dict.fromkeys((r.variant.payload_offset_m, r.variant.servos) for r in results))
    masses = sorted({r.variant.payload_kg for r in results})
    scales = sorted({r.variant.time_scale for r in results})
    margins = np.array([r.worst_margin_nm for r in results])
    bound = max(float(np.abs(margins).max()), 1e-3)
    norm = TwoSlopeNorm(vmin=-bound, vcenter=0.0, vmax=bound)
    fig, axes = plt.subplots(
        1,
        len(panels),
        figsize=(1.5 + 1.9 * len(masses) * len(panels), 2.0 + 0.8 * len(scales)),
        squeeze=False,
    )
    image = None
    for ax, (offset, servos) in zip(axes[0], panels, strict=True):
        grid = np.full((len(scales), len(masses)), np.nan)
        for r in results:
            v = r.variant
            if (v.payload_offset_m, v.servos) != (offset, servos):
                continue
            row, col = scales.index(v.time_scale), masses.index(v.payload_kg)
            grid[row, col] = r.worst_margin_nm
            text = "ok" if r.ok else "FAIL\n" + "\n".join(r.failed)
            if not r.ok:
                ax.add_patch(
                    Rectangle(
                        (col - 0.46, row - 0.46),
                        0.92,
                        0.92,
                        fill=False,
                        hatch="//",
                        edgecolor="tab:red",
                        linewidth=2.5,
                    )
                )
            dark = abs(r.worst_margin_nm) > 0.6 * bound
            ax.text(
                col,
                row,
                f"{text}\n{r.worst_margin_nm:.2f}",
                ha="center",
                va="center",
                fontsize=7,
                color="white" if dark else "black",
            )
        image = ax.imshow(grid, cmap="RdBu", norm=norm, aspect="auto")
        ax.set_xticks(range(len(masses)), [f"{m:g}" for m in masses])
        ax.set_yticks(range(len(scales)), [f"x{s:g}" for s in scales])
        ax.set_xlabel("payload (kg)")
        if len(set(servos)) == 1:
            names = f"all {servos[0]}"
        else:
            names = ", ".join(f"{j} {s}" for j, s in zip(joint_names, servos, strict=True))
        ax.set_title(f"{names}\noffset ({', '.join(f'{o:g}' for o in offset)}) m", fontsize=8)
    axes[0, 0].set_ylabel("time scale (x keyframe times)")
    fig.colorbar(image, ax=axes[0].tolist(), label="worst planned margin (N m)")
    fig.suptitle(
        "torque check per variant (cell: verdict, failed parts, worst planned margin in N m; "
        "hatched: fails)",
        fontsize=9,
        y=1.02,
    )
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path
