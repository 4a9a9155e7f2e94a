"""The closed loop's result and report: held-out error before and after with the spread
over splits, each effect's evidence, outlier rows, structure no effect explained, and
the printed summary."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_core.effects import OF_THE_RUN
from calib_core.effects.periodic import alias_periods
from calib_core.loop_structure import lack_of_fit, likely_causes, structure_tests
from calib_core.closed_loop.evidence import SEEN_NOT_ADDED
from calib_core.closed_loop.fitting import (
    Fit, error_summary, evaluate, fit_model, residuals_by_channel)
from calib_core.closed_loop.model import covariate_columns
from calib_core.closed_loop.outliers import find_outliers


@dataclass
class LoopResult:
    """Outcome of :func:`analyze`: the report (JSON-ready, SI units), the arrays the
    plots need (all rows) and the extended model as fitted on the fitting rows."""

    report: dict
    holdout: np.ndarray                 # bool (N,)
    residuals_before: np.ndarray        # (N, k), base model fitted on the training rows
    residuals_after: np.ndarray         # (N, k), extended model
    covariates: dict = field(default_factory=dict)   # name -> (N,)
    fit: Fit | None = None
    # In the channels (N, C): the base model's residuals, the extended model's, and each
    # added effect's fitted term (name -> (N, C)), for partial-residual plots.
    channel_before: np.ndarray | None = None
    channel_after: np.ndarray | None = None
    effect_terms: dict = field(default_factory=dict)


def _merged(splits: list, attribute: str, keep: list) -> dict:
    """A per-split dict merged over the splits (first split first), less the ``keep`` names."""
    out = {}
    for split in splits:
        for name, value in getattr(split, attribute).items():
            if name not in keep and name not in out:
                out[name] = value
    return out


def _unexplained(machine, config, final: Fit, train, covariates: dict, outliers: dict,
                 seen: list, tried: dict | None, structure: list | None) -> list:
    """What the extended model leaves: the effects seen and not added first, then the
    structure tests' findings on the fitting rows (each with its unit, likely causes and
    what trying the matching candidate gave) and, where settings were repeated, the lack
    of fit between the cells."""
    unexplained = [dict(item) for item in structure] if structure is not None else \
        structure_tests(machine.channels, residuals_by_channel(machine, final, train),
                        {k: v[train] for k, v in covariates.items()}, config.alpha)
    # A reversal changing with position that the trend alone explains is the trend, named
    # on its own (loop_structure).
    unexplained = [item for item in unexplained
                   if item.get('p_beyond_trend', 0.0) < config.alpha]
    scale = machine.channel_scale(final.base)
    if scale is not None:
        # The structure tests see the channels; people read the residuals' unit.
        for item in unexplained:
            factor = scale[machine.channels.index(item['component'].removeprefix('residual_'))]
            for key in ('structure_rms', 'residual_rms', 'pure_error_sigma'):
                if key in item:
                    item[key] = item[key] * float(factor)
    if machine.channel_units:
        own = dict(zip(machine.channels, machine.channel_units))
        for item in unexplained:
            item['unit'] = own[item['component'].removeprefix('residual_')]
            along = next((c for c in machine.channels if item['covariate'].endswith(f'_{c}')), None)
            item['covariate_unit'] = own.get(along, '')
    groups = machine.replicates()
    if groups is not None:
        # A gross row (the first approach's transient) is named under outliers; in a cell
        # of five repeats it would pass for scatter and hide the structure between cells.
        named = np.isin(train, [o['row'] for o in outliers['rows']])
        lack = lack_of_fit(final.residuals[~named], groups[train][~named],
                           final.parameter_count, config.alpha)
        if lack:
            unexplained.insert(0, dict(
                lack, kind='lack of fit', component='residual',
                covariate='replicate cells (one setting repeated, e.g. target and direction)',
                remedy=('the data support a compensation table per cell (mean error per '
                        'target and direction): a compensation table, not a physical model')))
    for item in unexplained:
        item['likely_causes'] = likely_causes(item)
        why = (tried or {}).get((item['kind'], item['component'], item['covariate']))
        if why:
            item['candidate_tried'] = why
    return list(seen) + unexplained


def _effects_added(final: Fit, std: np.ndarray, evidence: dict, frequency: dict) -> list:
    """Each added effect described: values and sigmas, what is not determined, aliases of
    a period on a regular grid, and its evidence with how often it was chosen."""
    effects_added = []
    for k, prepared in enumerate(final.effects):
        item = evidence[prepared.effect.name]
        entry = prepared.describe(final.values[k], std[final.effect_slice(k)])
        undetermined = getattr(prepared.effect, 'undetermined', None)
        vague = undetermined and undetermined(entry['parameters'], entry['std_devs'],
                                              prepared.notes)
        if vague:
            entry['parameters_not_determined'] = vague
        entry['round'] = item['round']
        if 'grid_spacing_m' in entry:
            entry['aliases_m'] = {channel: alias_periods(entry['parameters'][f'period_{channel}'], step)
                                  for channel, step in entry['grid_spacing_m'].items()
                                  if f'period_{channel}' in entry['parameters']}
        entry['evidence'] = dict(item['evidence'],
                                 selection_frequency=frequency.get(prepared.effect.name, 0.0))
        effects_added.append(entry)
    return effects_added


def _pooled_held_out(machine, splits: list, final: Fit) -> tuple:
    """The held-out error before and after pooled over every split (the final model
    refitted on each split's fitting rows), the figures per split, and which rows were
    held out at least once."""
    by_split, pooled_before, pooled_after = [], [], []
    for split in splits:
        rows = np.flatnonzero(split.holdout)
        # With nothing added the final model is the base model: its fit is the split's.
        refitted = (fit_model(machine, final.base, final.effects, final.values, split.train)
                    if final.effects else split.base_fit)
        pooled_before.append(evaluate(machine, split.base_fit, rows))
        pooled_after.append(evaluate(machine, refitted, rows))
        before, after = (error_summary(machine, r)
                         for r in (pooled_before[-1], pooled_after[-1]))
        by_split.append({'rms_before': before['rms'], 'rms_after': after['rms'],
                         'max_before': before['max'], 'max_after': after['max'],
                         'held_out': int(len(rows))})
    return (error_summary(machine, np.concatenate(pooled_before)),
            error_summary(machine, np.concatenate(pooled_after)), by_split,
            np.any([split.holdout for split in splits], axis=0))


def loop_result(machine, config, splits: list, final: Fit, evidence: dict, frequency: dict,
                not_identifiable: dict, rejected: dict, min_effect: float,
                seen: list = (), tried: dict | None = None,
                structure: list | None = None) -> LoopResult:
    """The report and arrays of :func:`analyze` (step 4 of the module's list): ``seen``
    are the effects chosen on some split and not added (they lead ``unexplained``),
    ``tried`` what trying an effect on a flagged structure gave, by (kind, component,
    covariate), ``structure`` the structure tests' findings on ``final`` where they ran
    already."""
    primary = splits[0]
    every = np.arange(len(machine))
    holdout, train = primary.holdout, primary.train
    before_all = evaluate(machine, primary.base_fit, every)
    after_all = evaluate(machine, final, every)
    context = machine.context(final.base, every)
    covariates = covariate_columns(machine, context)
    effect_terms = {prepared.effect.name: prepared.term(np.asarray(values, float), context)
                    for prepared, values in zip(final.effects, final.values)}
    outliers = find_outliers(machine, after_all, covariates, min_effect)
    unexplained = _unexplained(machine, config, final, train, covariates, outliers, seen,
                               tried, structure)
    std = final.std_devs()
    nb = len(final.base.free_names)
    held_before, held_after, by_split, held_once = _pooled_held_out(machine, splits, final)
    names = final.names()
    report = {
        'machine': machine.name,
        'base_model': machine.base_model,
        'unit': machine.unit,
        'channels': list(machine.channels),
        'rows': {'total': len(machine), 'fitting': int(len(train)),
                 'held_out': int(holdout.sum()),
                 'held_out_pooled': int(sum(s['held_out'] for s in by_split)),
                 'held_out_at_least_once': int(held_once.sum())},
        'config': {'holdout_fraction': config.holdout_fraction, 'folds': config.folds,
                   'alpha': config.alpha, 'max_effects': config.max_effects,
                   'seed': config.seed, 'splits': config.splits,
                   'min_frequency': config.min_frequency, 'min_effect': min_effect},
        'effects_added': _effects_added(final, std, evidence, frequency),
        'rms_before': held_before['rms'], 'max_before': held_before['max'],
        'rms_after': held_after['rms'], 'max_after': held_after['max'],
        'held_out_by_split': by_split,
        'fitting_rms_before': error_summary(machine, before_all[~holdout])['rms'],
        'fitting_rms_after': error_summary(machine, after_all[~holdout])['rms'],
        'base_parameters': {'before': primary.base_fit.base.as_dict(),
                            'after': final.base.as_dict(),
                            'units': final.base.units(),
                            'std_devs_after': dict(zip(final.base.free_names,
                                                       map(float, std[:nb])))},
        'candidates': list(machine.candidates),
        'selection_frequency': frequency,
        'skipped': _merged(splits, 'skipped', names),
        'not_identifiable': not_identifiable,
        'rejected': rejected,
        'below_minimum_effect': _merged(splits, 'too_small', names),
        'rounds': primary.rounds,
        'unexplained': unexplained,
        'outliers': outliers,
    }
    return LoopResult(_plain(report), holdout, before_all, after_all, covariates, final,
                      residuals_by_channel(machine, primary.base_fit, every),
                      residuals_by_channel(machine, final, every), effect_terms)


def why_not_in_force(effects_added: list) -> str:
    """Why a loop's extended model must not become the calibration in force: a sentence
    naming the added effects (report entries with a ``name``) that describe the run
    measured rather than the machine (OF_THE_RUN); '' where none does."""
    of_the_run = sorted({effect['name'] for effect in effects_added} & set(OF_THE_RUN))
    if not of_the_run:
        return ''
    return (f'{", ".join(of_the_run)} describe(s) the run measured, not the machine: nothing '
            'put in force (measure again at a steady temperature, or call without apply for '
            'the report)')


def _plain(value):
    """``value`` with numpy scalars and arrays made Python numbers and lists, so the
    report serialises to JSON and YAML alike."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _in_small_units(value: float, unit: str) -> tuple[float, str]:
    """m as um and rad as urad, for the printed lines."""
    return (value * 1e6, {'m': 'um', 'rad': 'urad'}[unit]) if unit in ('m', 'rad') else (value, unit)


def _effect_lines(effect: dict, factor: float, unit: str) -> list:
    """An added effect: its values and evidence, then what it leaves undetermined."""
    vague = effect.get('parameters_not_determined', {})
    values = ', '.join(f'{k} {v:.4g} +- {effect["std_devs"][k]:.2g} {effect["units"][k]}'
                       for k, v in effect['parameters'].items() if k not in vague)
    evidence = effect['evidence']
    found = evidence.get('from_structure')
    how = f'chosen in {evidence["selection_frequency"]:.0%} of splits'
    if found:
        how = (f'for the {found["kind"]} the structure test found in {found["component"]} '
               f'against {found["covariate"]}')
    elif 'replaces' in evidence:
        how = (f'in place of {evidence["replaces"]}, as good on held-out rows with fewer '
               f'parameters (x {evidence["heldout_ratio_to_replaced"]:.3f})')
    lines = [f'  added {effect["name"]} ({how}, p = {evidence["p_value"]:.2g}, '
             f'explains {evidence["explained_rms"] * factor:.3g} {unit} RMS): {values}']
    for name, why in vague.items():
        lines.append(f'    {name} not determined: {why}')
    for channel, why in effect.get('channels_not_determined', {}).items():
        lines.append(f'    {effect["name"]} on {channel}: not determined, {why}; '
                     f'nothing added there')
    for channel in effect.get('legs_with_mean_play', []):
        lines.append(f'    {effect["name"]} on {channel}: the mean of the others (its load '
                     f'changes side too rarely to fit its own)')
    for why in effect.get('channels_not_tested', []):
        lines.append(f'    {effect["name"]} not tested on {why}')
    for channel, aliases in effect.get('aliases_m', {}).items():
        lines.append(f'    period_{channel}: the targets lie every '
                     f'{effect["grid_spacing_m"][channel] * 1e3:.4g} mm, where '
                     f'{", ".join(f"{p * 1e3:.4g}" for p in aliases)} mm take the same '
                     f'values: the screw\'s lead decides (irregular targets would tell them '
                     f'apart)')
    return lines


def _held_out_lines(report: dict, factor: float, unit: str) -> list:
    """The held-out error pooled over the splits, and its spread over them."""
    spread = report.get('held_out_by_split', [])
    rows = report['rows']
    lines = [f'  held out, pooled over the {len(spread)} splits ({rows["held_out_pooled"]} '
             f'rows held out, {rows["held_out_at_least_once"]} of {rows["total"]} at least '
             f'once): RMS {report["rms_before"] * factor:.3g} -> '
             f'{report["rms_after"] * factor:.3g} {unit}, max '
             f'{report["max_before"] * factor:.3g} -> {report["max_after"] * factor:.3g} {unit}']
    ratios = [s['rms_after'] / s['rms_before'] for s in spread if s['rms_before'] > 0]
    if len(ratios) > 1:
        lines.append(f'  held-out RMS after / before over the {len(spread)} splits: '
                     f'{min(ratios):.2f} to {max(ratios):.2f}')
    return lines


def _outlier_lines(outliers: dict, factor: float, unit: str) -> list:
    if not outliers.get('count'):
        return []
    name = outliers.get('stratum_name', '')
    described = '; '.join(
        f'row {o["row"]} ('
        + ', '.join(([f'{name} {o[name]}'] if name in o else [])
                    + [f'{k} {v:.4g}' for k, v in o['covariates'].items()])
        + f'): {o["error"] * factor:.3g} {unit}' for o in outliers['rows'][:5])
    lines = [f'  OUTLIERS: {outliers["count"]} row(s) off by more than '
             f'{outliers["limit_sigmas"]:.3g} robust sigma '
             f'({outliers["limit"] * factor:.3g} {unit}; '
             f'robust sigma {outliers["robust_sigma"] * factor:.3g} {unit}) '
             f'under the extended model, e.g. {described}']
    for stratum in outliers.get('strata', []):
        lines.append(f'    {stratum["outliers"]} of them in {name} {stratum["label"]} (of its '
                     f'{stratum["rows"]} rows): the {name} as a whole disagrees with the rest '
                     f'(mis-detected or mis-ordered points?); check it, or leave it out and '
                     f'analyse again')
    return lines


def _unexplained_lines(item: dict, report_unit: str, factor: float, unit: str) -> list:
    """One unexplained item: an effect seen and not added, with its evidence, or
    structure no candidate explains, with its likely causes."""
    if item['kind'] == SEEN_NOT_ADDED:
        where = f' on {", ".join(item["channels"])}' if item['channels'] else ''
        gain = (f', held-out RMS pooled over the splits {-item["pooled_gain"]:+.1%} with it'
                if 'pooled_gain' in item else '')
        return [f'  UNEXPLAINED (seen, not added) {item["effect"]}{where}: chosen in '
                f'{item["splits_chosen"]} of {item["splits"]} splits (p = '
                f'{item["p_value"]:.2g}, explains {item["structure_rms"] * factor:.3g} '
                f'{unit} RMS there{gain}); kept out: {item["why_not_added"]}']
    period = ''
    if 'period' in item:
        period = (f' (period {np.degrees(item["period"]):.4g} deg)'
                  if item.get('covariate_unit') == 'rad' else
                  f' (period {item["period"] * 1e3:.4g} mm)')
    size, label = _in_small_units(item['structure_rms'], item.get('unit', report_unit))
    scatter = ''
    if 'pure_error_sigma' in item:
        repeat, _ = _in_small_units(item['pure_error_sigma'], item.get('unit', report_unit))
        scatter = f' while the repeats scatter {repeat:.3g} {label}'
    same = f' (= {", ".join(item["same_as"])})' if item.get('same_as') else ''
    lines = [f'  UNEXPLAINED {item["kind"]}{period} of {item["component"]} against '
             f'{item["covariate"]}{same}: {size:.3g} {label} RMS{scatter} '
             f'(p = {item["p_value"]:.2g}); could be {item["likely_causes"]}']
    lines += [f'    {item[key]}' for key in ('candidate_tried', 'remedy') if key in item]
    return lines


def format_report(report: dict) -> str:
    """Lines for people: what was added and how consistently, the held-out error before
    and after, what the data cannot determine, what was rejected or skipped, and what
    structure remains."""
    factor, unit = (1e6, 'um') if report['unit'] == 'm' else (1.0, report['unit'])
    config = report['config']
    lines = [f'{report["machine"]}: base model {report["base_model"]}',
             f'  rows: {report["rows"]["fitting"]} fitted, {report["rows"]["held_out"]} held '
             f'out; selection repeated over {config["splits"]} hold-out splits, an effect is '
             f'added when chosen in {config["min_frequency"]:.0%} of them and it explains at '
             f'least {config["min_effect"] * factor:.3g} {unit} RMS']
    for effect in report['effects_added']:
        lines += _effect_lines(effect, factor, unit)
    if not report['effects_added']:
        lines.append('  added nothing: no candidate effect is significant, identifiable and '
                     'chosen consistently')
    elif report['max_after'] > report['max_before']:
        lines.append(f'  NOTE: on these held-out rows the max grew (x '
                     f'{report["max_after"] / report["max_before"]:.3g}) though over the '
                     f'splits it grew by less than the RMS fell: a few rows the effects do not '
                     f'describe (see outliers)')
    lines += _held_out_lines(report, factor, unit)
    for name, reason in report.get('not_identifiable', {}).items():
        lines.append(f'  NOT IDENTIFIABLE {name}: {reason}')
    for name, reason in report.get('rejected', {}).items():
        lines.append(f'  rejected {name}: {reason}')
    for name, size in report.get('below_minimum_effect', {}).items():
        lines.append(f'  below the minimum effect size {name}: explains {size * factor:.3g} {unit} RMS')
    for name, reason in report['skipped'].items():
        lines.append(f'  not tested {name}: {reason}')
    lines += _outlier_lines(report.get('outliers', {}), factor, unit)
    for item in report['unexplained']:
        lines += _unexplained_lines(item, report['unit'], factor, unit)
    return '\n'.join(lines)
