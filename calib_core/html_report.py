"""A calibration or closed-loop report as one self-contained HTML page to hand on: the key
figures (before and after, held out), the parameters with their standard deviations, what
the loop added, left unexplained or rejected, the plan's prediction, the machine
description and instruments where the report holds them, the figures embedded, and the
whole report as JSON at the end, so the page loses nothing the file had.

One renderer for every machine: it reads the report's own keys (``parameters`` beside
``std_devs`` and ``units``; ``effects_added``, ``unexplained``, ``rejected``;
``rms_before``/``rms_after``; keys naming before, after, held-out, predicted) rather than a
layout per machine. The page has no script and loads nothing: images are data URIs.
"""
from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path
from typing import Iterable

from calib_core.storage import write_atomic

# Keys whose numbers are the report's key figures, wherever they sit (lower case).
_FIGURE_WORDS = ('before', 'after', 'held_out', 'evaluat', 'rms', 'max_', 'median',
                 'predicted', 'realised', 'repeatab', 'residual')
_UNIT_SUFFIXES = {'_m': 'm', '_rad': 'rad', '_px': 'px', '_um': 'um', '_urad': 'urad',
                  '_s': 's', '_k': 'K', '_mm': 'mm', '_deg': 'deg', '_arcsec': 'arcsec'}
# Parts of a report that are settings or per-split detail, not its key figures (they stay
# in the printed report and the JSON).
_NOT_FIGURES = {'config', 'held_out_by_split', 'base_parameters', 'rounds', 'candidates',
                'effects_added', 'selection_frequency', 'skipped', 'rejected'}
_MAX_FIGURES = 60          # key-figure rows: the rest stays in the JSON at the end
_MAX_LIST = 12             # numbers shown of a list before "... (n values)"

_STYLE = """
body{font-family:system-ui,sans-serif;max-width:72rem;margin:1.5rem auto;padding:0 1rem;
color:#222}
h1{font-size:1.5rem}h2{font-size:1.15rem;margin-top:2rem;border-bottom:1px solid #ccc}
table{border-collapse:collapse;margin:.5rem 0;font-size:.9rem}
td,th{border:1px solid #ddd;padding:.2rem .5rem;text-align:left;vertical-align:top}
th{background:#f3f3f3}td.num{text-align:right;font-variant-numeric:tabular-nums}
pre{background:#f7f7f7;padding:.6rem;white-space:pre-wrap;font-size:.8rem}
img{max-width:100%;border:1px solid #ddd}.meta{color:#555}.none{color:#777}
"""


def quantity(value, unit: str = '', sigma: float | None = None) -> str:
    """``value`` in ``unit`` as people read it: lengths in m shown in mm, um or nm and
    angles in rad in mrad or urad where that reads better; 4 significant digits, or with
    ``sigma`` (its standard deviation, same unit) as many decimals as show sigma's first
    two digits (a lead of 15.9972 mm known to 20 nm must not read 16 mm)."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return html.escape(str(value))
    if not math.isfinite(value):
        return str(value)
    factor, name = 1.0, unit
    scaled = {'m': ((1e-3, 1e3, 'mm'), (1e-6, 1e6, 'um'), (0.0, 1e9, 'nm')),
              'rad': ((1e-3, 1e3, 'mrad'), (0.0, 1e6, 'urad'))}.get(unit)
    if scaled and 0 < abs(value) < 0.1:
        factor, name = next((f, n) for floor, f, n in scaled if abs(value) >= floor)
    if isinstance(value, int) and factor == 1.0:
        return f'{value} {unit}'.strip()
    if isinstance(sigma, (int, float)) and math.isfinite(sigma) and sigma > 0:
        decimals = min(max(1 - math.floor(math.log10(sigma * factor)), 0), 12)
        return f'{value * factor:.{decimals}f} {name}'.strip()
    return f'{value * factor:.4g} {name}'.strip()


def _unit_of(key: str) -> str:
    lowered = key.lower()
    for suffix, unit in _UNIT_SUFFIXES.items():
        if lowered.endswith(suffix):
            return unit
    return ''


def _cell(value) -> str:
    if isinstance(value, float):
        return f'<td class="num">{quantity(value)}</td>'
    if isinstance(value, list) and all(isinstance(v, (int, float)) for v in value):
        shown = ', '.join(f'{v:.4g}' if isinstance(v, float) else str(v)
                          for v in value[:_MAX_LIST])
        more = f' ... ({len(value)} values)' if len(value) > _MAX_LIST else ''
        return f'<td>{shown}{more}</td>'
    if isinstance(value, (dict, list)):
        return f'<td>{_nested(value)}</td>'
    return f'<td>{html.escape(str(value))}</td>'


def _nested(value) -> str:
    """A dict as a key/value table, a list of dicts as one table, anything else as text."""
    if isinstance(value, dict):
        if not value:
            return '<span class="none">none</span>'
        rows = ''.join(f'<tr><th>{html.escape(str(k))}</th>{_cell(v)}</tr>'
                       for k, v in value.items())
        return f'<table>{rows}</table>'
    if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        columns = list(dict.fromkeys(k for v in value for k in v))
        head = ''.join(f'<th>{html.escape(str(c))}</th>' for c in columns)
        body = ''.join('<tr>' + ''.join(_cell(v.get(c, '')) for c in columns) + '</tr>'
                       for v in value)
        return f'<table><tr>{head}</tr>{body}</table>'
    if isinstance(value, list) and not value:
        return '<span class="none">none</span>'
    return html.escape(str(value))


def _walk(value, path=()):
    """(path, dict) for every dict in ``value``, depth first."""
    if isinstance(value, dict):
        yield path, value
        for key, item in value.items():
            yield from _walk(item, path + (str(key),))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            if isinstance(item, dict):
                yield from _walk(item, path + (str(index),))


def key_figures(report: dict) -> list[tuple[str, str]]:
    """(where, value with unit) for each number whose key says it is a before, after,
    held-out, predicted or residual figure; a loop report's held-out RMS and max first."""
    rows = []
    if 'rms_before' in report and 'rms_after' in report:
        unit = report.get('unit', '')
        for key in ('rms_before', 'rms_after', 'max_before', 'max_after'):
            if key in report:
                rows.append((f'held-out {key.replace("_", " ")}', quantity(report[key], unit)))
    for path, mapping in _walk(report):
        if len(path) > 4 or _NOT_FIGURES & set(path):
            continue
        for key, value in mapping.items():
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                continue
            where = '.'.join(path + (str(key),))
            if path == () and key in ('rms_before', 'rms_after', 'max_before', 'max_after'):
                continue
            if any(word in where.lower() for word in _FIGURE_WORDS):
                # A loop report's own figures are in its ``unit``; others name theirs.
                own = path == () and ('rms' in key or 'max' in key)
                unit = _unit_of(key) or (report.get('unit', '') if own else '')
                rows.append((where, quantity(value, unit)))
    return rows[:_MAX_FIGURES]


def parameter_tables(report: dict) -> list[tuple[str, list]]:
    """(where, rows of (name, value, sigma, unit)) for each ``parameters`` dict that has
    ``std_devs`` beside it, outside the loop's effects (they have their own table)."""
    tables = []
    for path, mapping in _walk(report):
        if 'effects_added' in path or 'candidates' in path:
            continue
        values, sigmas = mapping.get('parameters'), mapping.get('std_devs')
        if not (isinstance(values, dict) and isinstance(sigmas, dict)):
            continue
        units = mapping.get('units') if isinstance(mapping.get('units'), dict) else {}
        tables.append(('.'.join(path) or 'the report', [
            (name, value, sigmas.get(name), units.get(name, '')) for name, value in values.items()
            if isinstance(value, (int, float))]))
    return tables


def _parameters_html(rows: list) -> str:
    body = ''.join(
        f'<tr><td>{html.escape(name)}</td><td class="num">{quantity(value, unit, sigma)}</td>'
        f'<td class="num">{quantity(sigma, unit) if sigma is not None else "-"}</td>'
        f'<td>{html.escape(unit)}</td></tr>' for name, value, sigma, unit in rows)
    return ('<table><tr><th>parameter</th><th>value</th><th>standard deviation (1 sigma)</th>'
            f'<th>unit (SI)</th></tr>{body}</table>')


def _effects_html(effects: list) -> str:
    if not effects:
        return '<p class="none">nothing added</p>'
    rows = []
    for effect in effects:
        units = effect.get('units', {})
        evidence = effect.get('evidence', {})
        for name, value in effect.get('parameters', {}).items():
            sigma = effect.get('std_devs', {}).get(name)
            rows.append(
                f'<tr><td>{html.escape(str(effect.get("name", "")))}</td>'
                f'<td>{html.escape(str(effect.get("channel", effect.get("region", ""))))}</td>'
                f'<td>{html.escape(name)}</td>'
                f'<td class="num">{quantity(value, units.get(name, ""), sigma)}</td>'
                f'<td class="num">{quantity(sigma, units.get(name, "")) if sigma is not None else "-"}</td>'
                f'<td class="num">{quantity(evidence.get("p_value", ""))}</td></tr>')
    return ('<table><tr><th>effect</th><th>channel</th><th>parameter</th><th>value</th>'
            '<th>standard deviation</th><th>p-value</th></tr>' + ''.join(rows) + '</table>')


def _figure_html(path: Path) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode('ascii')
    name = html.escape(Path(path).name)
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{name}">'
            f'<figcaption class="meta">{name}</figcaption></figure>')


def render_html(report: dict, title: str, figures: Iterable[Path] = (),
                text: str = '') -> str:
    """The page for ``report`` (a JSON-able dict): ``figures`` (PNG files) embedded,
    ``text`` (the report as printed, if any) shown as it is."""
    sections = [f'<h1>{html.escape(title)}</h1>']
    meta = {k: report[k] for k in ('kind', 'machine', 'created', 'bag', 'data', 'source',
                                   'applied_to', 'not_applied') if k in report}
    if meta:
        sections.append('<p class="meta">' + '; '.join(
            f'{html.escape(k)}: {html.escape(str(v))}' for k, v in meta.items()) + '</p>')
    figures_rows = key_figures(report)
    sections.append('<h2>Key figures</h2>')
    sections.append(_nested(dict(figures_rows)) if figures_rows else
                    '<p class="none">the report holds no before/after figures</p>')
    for where, rows in parameter_tables(report):
        sections.append(f'<h2>Parameters ({html.escape(where)})</h2>' + _parameters_html(rows))
    if 'effects_added' in report:
        sections.append('<h2>Closed loop: effects added</h2>'
                        + _effects_html(report['effects_added']))
        sections.append('<h2>Unexplained</h2>' + _nested(report.get('unexplained', [])))
        sections.append('<h2>Rejected</h2>' + _nested(report.get('rejected', {})))
    for key in ('plan', 'prediction', 'description', 'instrument', 'instruments'):
        if key in report:
            sections.append(f'<h2>{html.escape(key.capitalize())}</h2>' + _nested(report[key]))
    if text:
        sections.append('<h2>The report as printed</h2><pre>' + html.escape(text) + '</pre>')
    for figure in figures:
        if Path(figure).is_file():
            sections.append('<h2>Figure</h2>' + _figure_html(figure))
    sections.append('<h2>The whole report (JSON)</h2><details><summary>show</summary><pre>'
                    + html.escape(json.dumps(report, indent=2, default=str)) + '</pre></details>')
    return ('<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>\n'
            + '\n'.join(sections) + '\n</body></html>\n')


def write_html(path, report: dict, title: str, figures: Iterable[Path] = (),
               text: str = '') -> Path:
    """:func:`render_html` written atomically to ``path``; returns the path."""
    return write_atomic(path, render_html(report, title, figures, text))
