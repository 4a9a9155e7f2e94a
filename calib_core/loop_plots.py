"""Pictures of a closed-loop run: each added effect drawn over its partial residuals (what
the extended model leaves plus the effect itself) against the covariate it follows, the
first structure left unexplained, residuals against each covariate and over the
workspace, before (base model) and after (extended model), and held-out error histograms."""
from __future__ import annotations

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from calib_core.closed_loop import LoopResult, MachineModel  # noqa: E402
from calib_core.effects import LIBRARY  # noqa: E402
from calib_core.figures import arrow_key, save_figure  # noqa: E402

_SCALES = {'m': (1e6, 'um'), 'px': (1.0, 'px'), 'rad': (1e6, 'urad')}
_MAX_COVARIATE_PANELS = 8
_MAX_EFFECT_PANELS = 4
_FEW_VALUES = 10      # a covariate with fewer distinct values is drawn as points, not a line
_COVARIATE_UNITS = {'position': 'm', 'direction': '+1 / -1', 'time': 's', 'temperature': 'K',
                    'load': 'N', 'image': 'normalised'}


def _component(machine: MachineModel, name: str, residuals: np.ndarray) -> np.ndarray:
    """The residual to plot against covariate ``name``: the matching channel's when the
    covariate belongs to one, else every component pooled (repeated covariate)."""
    if residuals.shape[1] == len(machine.channels):
        for c, channel in enumerate(machine.channels):
            if name.endswith(f'_{channel}'):
                return residuals[:, c]
    return residuals


def _vectors(ax, machine, result, workspace, factor: float, unit: str) -> None:
    """Residual vectors over the workspace, before and after on one scale, with a key."""
    place, place_unit = (1e3, 'mm') if machine.unit == 'm' else (1.0, machine.unit)
    xy = workspace * place
    span = np.ptp(xy, axis=0).max() or 1.0
    before, after = result.residuals_before * factor, result.residuals_after * factor
    largest = np.abs(before).max() or 1.0
    per_length = largest / (0.06 * span)          # residual unit per workspace unit of arrow
    for residuals, colour in ((before, 'tab:red'), (after, 'tab:blue')):
        arrows = ax.quiver(xy[:, 0], xy[:, 1], residuals[:, 0], residuals[:, 1], color=colour,
                           angles='xy', scale_units='xy', scale=per_length, width=0.003)
    arrow_key(ax, arrows, largest / 2, unit)
    ax.set_aspect('equal')
    ax.set_xlabel(f'x ({place_unit})')
    ax.set_ylabel(f'y ({place_unit})')
    small = np.abs(after).max() < 0.05 * largest
    ax.set_title('residual vectors on one scale (key below)\nred: base model; blue: after'
                 + (', too short to see' if small else ''), fontsize=9, loc='left')


def _covariate_scale(machine: MachineModel, name: str, kind: str) -> tuple[float, str]:
    """Factor and unit to plot covariate ``name`` in: a channel's position or angle in
    mm or deg by the channel's unit, the others in their own."""
    if kind not in ('position', 'angle'):
        return 1.0, _COVARIATE_UNITS.get(kind, '')
    units = dict(zip(machine.channels, machine.channel_units or ('m',) * len(machine.channels)))
    channel = next((c for c in machine.channels if name.endswith(f'_{c}')), None)
    unit = units.get(channel, machine.unit)
    return {'m': (1e3, 'mm'), 'rad': (180 / np.pi, 'deg')}.get(unit, (1.0, unit))


def _roughness(term: np.ndarray, covariate: np.ndarray) -> float:
    """How little ``term`` (n,) follows ``covariate`` (n,): its squared steps when the rows
    are sorted by the covariate, over its variance (near 0 for the covariate it is a
    function of)."""
    order = np.argsort(covariate, kind='stable')
    spread = float(np.sum((term - term.mean()) ** 2)) or 1.0
    return float(np.sum(np.diff(term[order]) ** 2)) / spread


def _named_channels(machine: MachineModel, result: LoopResult, effect: str) -> set:
    """The channels the report names ``effect``'s parameters on (``backlash_leg2``), or
    every channel where no parameter names one (a lens distortion, a squareness)."""
    entry = next((e for e in result.report.get('effects_added', []) if e['name'] == effect), {})
    named = {c for p in entry.get('parameters', {}) for c in machine.channels
             if p.endswith(f'_{c}')}
    return named or set(machine.channels)


def effect_panels(machine: MachineModel, result: LoopResult) -> list:
    """(effect, channel index, covariate name) per panel: each added effect on the
    channels the report names it on where its term is largest (at most
    :data:`_MAX_EFFECT_PANELS` in all), against the covariate its term follows most
    smoothly among those it is written in, the channel's own where the covariate is per
    channel (a leg's play against that leg's load, not another's equally smooth one)."""
    panels = []
    for name, term in result.effect_terms.items():
        size = np.sqrt(np.mean(term ** 2, axis=0))
        named = _named_channels(machine, result, name)
        for c in np.argsort(-size)[:3]:
            # Channels where the effect is small beside its largest are left to the numbers,
            # and a channel the report does not name it on (a leg given the mean play) is
            # not drawn as if it had been found there.
            if (size[c] < 0.5 * size.max() or size[c] <= 0 or len(panels) >= _MAX_EFFECT_PANELS
                    or machine.channels[c] not in named):
                continue
            varying = [k for k, z in result.covariates.items() if np.ptp(z) > 0]
            # The covariates the effect is written in, when the data have them.
            declared = tuple('image_radius' if key == 'normalized' else key
                             for key in LIBRARY[name].requires)
            candidates = [k for k in varying if k.startswith(declared)] or varying
            if candidates:
                panels.append((name, int(c), _smoothest(term[:, c], candidates, result,
                                                        machine.channels[c],
                                                        machine.channels)))
    return panels


def _smoothest(term: np.ndarray, candidates: list, result: LoopResult, channel: str,
               channels) -> str:
    """The covariate ``term`` (n,) follows most smoothly (a squareness on x against y, not
    x); among those as smooth (within 10 %), the channel's own (a leg's play against its
    own load, not another leg's equally smooth one), then one of no channel, then the
    finer."""
    rough = {k: _roughness(term, result.covariates[k]) for k in candidates}
    best = min(rough.values())
    smooth = [k for k in candidates if rough[k] <= 1.1 * best + 1e-9]

    def preference(k):
        own = k.endswith(f'_{channel}')
        shared = not any(k.endswith(f'_{other}') for other in channels)
        return (not own, not shared, -len(np.unique(result.covariates[k])))
    return min(smooth, key=preference)


def _channel_scale(machine: MachineModel, c: int) -> tuple[float, str]:
    units = machine.channel_units or (machine.unit,) * len(machine.channels)
    return _SCALES.get(units[c], (1.0, units[c]))


def _abscissa(machine: MachineModel, result: LoopResult, covariate: str):
    """A covariate's values in the unit it is plotted in, and the axis label."""
    kind = covariate.split('_')[0]
    scale, unit = _covariate_scale(machine, covariate, kind)
    z = result.covariates[covariate]
    if kind == 'time':
        return (z - np.min(z)) * scale, f'{covariate} since the first row ({unit})'
    return z * scale, f'{covariate} ({unit})' if unit else covariate


def _period(machine, result, effect: str, c: int, covariate: str) -> float | None:
    """The fitted period (m or rad) of a periodic ``effect`` on channel ``c`` where it is
    drawn against that channel's position, else None."""
    entry = next((e for e in result.report.get('effects_added', []) if e['name'] == effect),
                 {})
    period = entry.get('parameters', {}).get(f'period_{machine.channels[c]}')
    own_position = covariate.endswith(f'_{machine.channels[c]}')
    return float(period) if period and own_position else None


def _draw_effect(ax, machine, result, effect: str, c: int, covariate: str) -> None:
    """The partial residual of ``effect`` on channel ``c`` (what the extended model leaves
    plus the effect) against ``covariate``, with the fitted effect at every row over it.

    The fitted effect is drawn as points, the values it takes at the rows: a line through
    rows sorted by one covariate zigzags wherever the effect is not a function of it
    alone, or is sampled more sparsely than it varies. A periodic effect is drawn
    against the position modulo its fitted period, so the rows trace one period. The base
    model's residual is left to the covariate panels: refitted with the effect, the base
    model absorbs part of it, and the two would sit apart by that part."""
    factor, unit = _channel_scale(machine, c)
    x, label = _abscissa(machine, result, covariate)
    period = _period(machine, result, effect, c, covariate)
    if period is not None:
        scale, _ = _covariate_scale(machine, covariate, covariate.split('_')[0])
        x = np.mod(x, period * scale)
        label = f'{label.rsplit(" (", 1)[0]} modulo the fitted period {period * scale:.4g}' \
                f' ({label.rsplit(" (", 1)[1]}'
    term = result.effect_terms[effect][:, c] * factor
    ax.plot(x, result.channel_after[:, c] * factor + term, '.', ms=4, color='tab:blue',
            alpha=0.6, label='partial residual: after + this effect')
    few = len(np.unique(np.round(x, 9))) < _FEW_VALUES
    ax.plot(x, term, 'k_' if few else 'k.', ms=14 if few else 4,
            label='fitted effect at each row')
    ax.set_xlabel(label)
    ax.set_ylabel(f'{machine.channels[c]} residual ({unit})')
    ax.set_title(f'{effect} on {machine.channels[c]}', fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)


def _draw_unexplained(ax, machine, result, item: dict) -> None:
    """The first unexplained structure: the extended model's residual of its component
    against its covariate, with the mean in bins of the covariate."""
    c = machine.channels.index(item['component'].removeprefix('residual_'))
    factor, unit = _channel_scale(machine, c)
    covariate = item['covariate']
    x, label = _abscissa(machine, result, covariate)
    y = result.channel_after[:, c] * factor
    ax.plot(x, y, '.', ms=3, color='tab:blue', alpha=0.5, label='after loop')
    edges = np.unique(np.quantile(x, np.linspace(0, 1, 17)))
    which = np.clip(np.searchsorted(edges, x, side='right') - 1, 0, len(edges) - 2)
    means = [(x[which == b].mean(), y[which == b].mean()) for b in range(len(edges) - 1)
             if np.any(which == b)]
    ax.plot(*np.array(means).T, 'k-', lw=1.5, label='mean in bins')
    ax.set_xlabel(label)
    ax.set_ylabel(f'{machine.channels[c]} residual ({unit})')
    ax.set_title(f'UNEXPLAINED {item["kind"]} (p = {item["p_value"]:.2g})', fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)


def _panel_covariates(machine: MachineModel, result: LoopResult) -> list:
    """(name, values) of the covariates worth a panel: those the added effects act on
    first, those where the loop changed the residuals most first among them, one panel per
    covariate that looks different (a rotary axis's reading and its position differ by
    microradians: the same panel twice)."""
    needed = {kind for e in result.report['effects_added']
              for kind in LIBRARY[e['name']].requires}

    def change(name):
        """How much the loop changed the residuals this covariate's panel shows."""
        moved = (_component(machine, name, result.residuals_before)
                 - _component(machine, name, result.residuals_after))
        return float(np.sqrt(np.mean(np.square(moved))))
    covariates = sorted(((name, z) for name, z in result.covariates.items() if np.ptp(z) > 0),
                        key=lambda item: (item[0].split('_')[0] not in needed,
                                          -change(item[0])))
    distinct = []
    for name, z in covariates:
        if not any(np.shape(z) == np.shape(w)
                   and np.max(np.abs(np.subtract(z, w))) < 1e-3 * np.ptp(z)
                   for _, w in distinct):
            distinct.append((name, z))
    return distinct


def _draw_covariate(ax, machine: MachineModel, result: LoopResult, name: str, z, factor: float,
                    unit: str) -> None:
    """The residuals before and after against covariate ``name``: a direction side by
    side at -1 and +1, a clock time from the first row, anything else in its unit."""
    kind = name.split('_')[0]
    scale, covariate_unit = _covariate_scale(machine, name, kind)
    for shift, residuals, colour, label in (
            (-0.12, result.residuals_before, 'tab:red', 'base model'),
            (0.12, result.residuals_after, 'tab:blue', 'after loop')):
        r = _component(machine, name, residuals) * factor
        zz = np.broadcast_to(z[:, None], r.shape) if r.ndim == 2 else z
        if kind == 'direction':   # a category: side by side at -1 and +1, not an axis
            zz = zz + shift
        elif kind == 'time':      # clock times (epoch s) read best from the first row
            zz = (zz - np.min(z)) * scale
        else:
            zz = zz * scale
        ax.plot(zz.ravel(), r.ravel(), '.', ms=3, color=colour, alpha=0.6, label=label)
    if kind == 'direction':
        ax.set_xticks([-1, 1], ['-1: from above', '+1: from below'])
        ax.set_xlim(-1.6, 1.6)
        ax.set_xlabel(name)
    elif kind == 'time':
        ax.set_xlabel(f'{name} since the first row ({covariate_unit})')
    else:   # a count (sequence, cycle) has no unit to show
        ax.set_xlabel(f'{name} ({covariate_unit})' if covariate_unit else name)
    ax.set_ylabel(f'residual ({unit})')
    ax.grid(alpha=0.3)


def _draw_held_out(ax, machine: MachineModel, result: LoopResult, factor: float,
                   unit: str) -> None:
    """The held-out rows' errors before and after, one histogram on one scale."""
    report, held = result.report, result.holdout
    before = machine.row_errors(result.residuals_before[held]) * factor
    after = machine.row_errors(result.residuals_after[held]) * factor
    bins = np.linspace(0, max(before.max(), after.max()) * 1.02, 30)
    ax.hist(before, bins, color='tab:red', alpha=0.6,
            label=f'base: RMS {report["rms_before"] * factor:.3g} {unit}')
    ax.hist(after, bins, color='tab:blue', alpha=0.6,
            label=f'after: RMS {report["rms_after"] * factor:.3g} {unit}')
    ax.set_xlabel(f'held-out error ({unit})')
    ax.set_ylabel('count')
    ax.legend(fontsize=8)


def plot_loop(path, machine: MachineModel, result: LoopResult) -> None:
    """Write the figure for ``result`` to ``path`` (PNG): the added effects' panels, the
    first unexplained structure, the residuals against the covariates, the held-out
    errors and, for two-channel machines, the residual vectors over the workspace."""
    report = result.report
    factor, unit = _SCALES.get(machine.unit, (1.0, machine.unit))
    distinct = _panel_covariates(machine, result)
    effects = effect_panels(machine, result) if result.channel_after is not None else []
    unexplained = [item for item in report.get('unexplained', [])
                   if item['component'].removeprefix('residual_') in machine.channels
                   and item['covariate'] in result.covariates][:1]
    extra = len(effects) + len(unexplained)
    covariates = distinct[:max(_MAX_COVARIATE_PANELS - extra, 3)]
    workspace = machine.workspace()
    vectors = workspace is not None and result.residuals_after.shape[1] == 2
    panels = extra + len(covariates) + 1 + vectors
    cols = min(3, panels)
    rows = int(np.ceil(panels / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 3.6 * rows), squeeze=False)
    axes = axes.ravel()
    for ax, (effect, c, covariate) in zip(axes, effects):
        _draw_effect(ax, machine, result, effect, c, covariate)
    for ax, item in zip(axes[len(effects):], unexplained):
        _draw_unexplained(ax, machine, result, item)
    for ax, (name, z) in zip(axes[extra:], covariates):
        _draw_covariate(ax, machine, result, name, z, factor, unit)
    if covariates:
        axes[extra].legend(loc='best', fontsize=8)
    k = extra + len(covariates)
    _draw_held_out(axes[k], machine, result, factor, unit)
    if vectors:
        _vectors(axes[k + 1], machine, result, workspace, factor, unit)
    for ax in axes[panels:]:
        ax.axis('off')
    names = ', '.join(e['name'] for e in report['effects_added']) or 'nothing'
    fig.suptitle(f'{report["machine"]}: added {names}; held-out RMS '
                 f'{report["rms_before"] * factor:.3g} -> {report["rms_after"] * factor:.3g} {unit}')
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.35 / fig.get_figheight()))   # room for the title
    save_figure(fig, path, [__file__])
    plt.close(fig)
