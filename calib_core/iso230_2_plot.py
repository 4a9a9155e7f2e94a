"""The ISO 230-2 plot every laser-calibration package draws: per target the mean deviation
of each direction with +-2 s, and the bidirectional mean, as measured and after
compensation on one scale."""
from __future__ import annotations

import textwrap

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from calib_core.figures import save_figure  # noqa: E402


def _values(per_target: dict, key: str) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in per_target[key]], float)


def _panel(ax, figures: dict, title: str) -> None:
    cells = figures['per_target']
    target = np.asarray(cells['target']) * 1e3
    for key, sign, colour, marker in (('up', 'up', 'tab:blue', '^'),
                                      ('down', 'down', 'tab:red', 'v')):
        mean, s = _values(cells, f'mean_{key}') * 1e6, _values(cells, f's_{key}') * 1e6
        if np.all(np.isnan(mean)):
            continue
        ax.plot(target, mean, marker=marker, color=colour, label=f'mean, approached {sign}')
        ax.fill_between(target, mean - 2 * s, mean + 2 * s, color=colour, alpha=0.15,
                        label=f'+-2 s, {sign}')
    both = (_values(cells, 'mean_up') + _values(cells, 'mean_down')) / 2 * 1e6
    if np.any(np.isfinite(both)):
        ax.plot(target, both, 'k--', lw=1, label='bidirectional mean')
    bi = figures['bidirectional']
    shown = ', '.join(f'{name} {bi[name] * 1e6:.2f}' for name in ('A', 'B', 'E', 'M', 'R')
                      if bi.get(name) is not None)
    # Wrapped to the panel's width: a long "after" label ran off the figure's edge.
    title = '\n'.join(textwrap.wrap(title, 60))
    ax.set_title(f'{title}\n{shown} um' if shown else title, fontsize=10)
    ax.set_xlabel('target position (mm)')
    ax.set_ylabel('deviation, measured - target (um)')
    ax.grid(alpha=0.3)


def plot_iso230_2(path, before: dict, after: dict, after_label: str) -> None:
    """``before`` and ``after``: ``iso230_2.figures`` results (m); one y scale."""
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6), sharey=True)
    _panel(axes[0], before, 'ISO 230-2, as measured')
    _panel(axes[1], after, f'ISO 230-2, {after_label}')
    axes[0].legend(fontsize=8, loc='best')
    fig.tight_layout()
    save_figure(fig, path, [__file__])
    plt.close(fig)
