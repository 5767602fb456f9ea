"""Figures of a run (PNG, matplotlib's Agg backend: no display needed)."""

from __future__ import annotations


__all__ = ["plot_tracking"]


def plot_tracking(path, t, q_d, q, tau, title: str) -> None:
    """Joint tracking (paper Fig. 4), tracking errors (Fig. 5) and torque commands, one PNG.

    Parameters
    ----------
    t : ndarray, shape (n_samples,), s
    q_d, q, tau : ndarray, shape (n_samples, n_joints), rad and N·m
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True, constrained_layout=True)
    for k in range(q.shape[1]):
        (line,) = axes[0].plot(t, q[:, k], label=f"q{k + 1}")
        axes[0].plot(t, q_d[:, k], "--", color=line.get_color(), lw=0.8)
        axes[1].plot(t, 1e3 * (q_d[:, k] - q[:, k]), label=f"e{k + 1}")
        axes[2].plot(t, tau[:, k], label=f"τ{k + 1}")
    axes[0].set_ylabel("joint position (rad)\n— actual, -- desired")
    axes[1].set_ylabel("tracking error (mrad)")
    axes[2].set_ylabel("torque command (N·m)")
    axes[2].set_xlabel("time (s)")
    for ax in axes:
        ax.grid(True, lw=0.3)
        ax.legend(loc="upper right", fontsize=8, ncol=min(q.shape[1], 6))
    axes[0].set_title(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
