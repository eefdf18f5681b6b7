"""A self-contained ``report.html``: metrics, run config, timing and figures in one file.

Images are embedded as base64 ``data:`` URIs (PNG, or SVG when only an SVG is given), so the
file can be mailed or archived alone. When a figure exists as both ``name.png`` and
``name.svg``, the PNG is embedded once and the pair counts as one figure.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import json
from pathlib import Path

from hub.analysis.glossary import FIGURES, METRICS, TIMING
from hub.analysis.glossary import metric as glossary_entry
from hub.analysis.output import write_whole
from hub.analysis.spikes import AnalysisInputError

_MIME = {".png": "image/png", ".svg": "image/svg+xml"}

_CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; } td, th { padding: 2px 10px; border-bottom: 1px solid #eee; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
pre { background: #f6f6f6; padding: 0.8em; overflow-x: auto; font-size: 0.85em; }
figure { margin: 1em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.85em; color: #555; }
td.def { font-size: 0.85em; color: #555; }
"""


def _fmt(value) -> str:
    if value is None:
        return "—"
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, dict):  # e.g. per endpoint: {"body": {"median": 1.2, ...}}
        return "; ".join(f"{html.escape(str(k))}: {_fmt(v)}" for k, v in value.items())
    return html.escape(str(value))


def _table(rows: dict, glossary: dict) -> str:
    """Label (with unit) | value | definition, one row per key (the key in a tooltip)."""
    body = []
    for k, v in rows.items():
        label, definition = glossary_entry(str(k), glossary)
        body.append(
            f"<tr><th style='text-align:left' title='{html.escape(str(k))}'>"
            f"{html.escape(label)}</th><td class='num'>{_fmt(v)}</td>"
            f"<td class='def'>{html.escape(definition)}</td></tr>"
        )
    return f"<table>{''.join(body)}</table>"


def _summary_html(text: str) -> str:
    """A markdown table (lines starting with ``|``) as an HTML table, other lines as
    paragraphs; text that is neither stays preformatted."""
    lines = [ln.strip() for ln in text.strip().splitlines()]
    if not any(ln.startswith("|") for ln in lines):
        return f"<pre>{html.escape(text)}</pre>"
    parts, rows = [], []

    def flush() -> None:
        if not rows:
            return
        head, *body = rows
        cells = "".join(f"<th>{html.escape(c)}</th>" for c in head)
        trs = "".join(
            "<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in body
        )
        parts.append(f"<table><tr>{cells}</tr>{trs}</table>")
        rows.clear()

    for ln in lines:
        if ln.startswith("|"):
            cells = [c.strip() for c in ln.strip("|").split("|")]
            if not all(set(c) <= set("-: ") for c in cells):  # not the |---| rule
                rows.append([c.replace("**", "") for c in cells])
        else:
            flush()
            if ln:
                parts.append(f"<p>{html.escape(ln)}</p>")
    flush()
    return "\n".join(parts)


def _pick_figures(figures) -> list[Path]:
    """One file per figure stem, preferring PNG; keeps the given order."""
    chosen: dict[tuple[Path, str], Path] = {}
    for f in figures:
        p = Path(f)
        if p.suffix.lower() not in _MIME:
            raise AnalysisInputError(f"figures must be .png or .svg files, got {p}")
        if not p.is_file():
            raise AnalysisInputError(f"figure file {p} does not exist")
        key = (p.parent, p.stem)
        if key not in chosen or p.suffix.lower() == ".png":
            chosen[key] = p
    return list(chosen.values())


def write_report(
    path,
    metrics: dict,
    config: dict,
    figures,
    title: str = "NeuVision run report",
    timing: dict | None = None,
    summary: str | None = None,
) -> Path:
    """Write the self-contained HTML report and return its path.

    Parameters
    ----------
    path : output file (``report.html``); its folder is created if needed.
    metrics : the metrics dict (e.g. from ``metrics.compute_metrics``); shown as a table.
    config : the run's config (any JSON-able mapping); shown as formatted JSON.
    figures : paths of PNG/SVG figure files, embedded in the given order.
    timing : optional mapping (e.g. wall time, steps, late replies) shown as a table.
    summary : optional preformatted text (e.g. a markdown table) shown first.

    Metrics and timing are shown with their labels, units and definitions, figures with
    their captions (:mod:`hub.analysis.glossary`).
    """
    out = Path(path)
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        f"<p>Written {_dt.datetime.now(_dt.UTC).isoformat(timespec='seconds')}.</p>",
    ]
    if summary:
        parts += ["<h2>Summary</h2>", _summary_html(summary)]
    parts += [
        "<h2>Metrics</h2>",
        _table(metrics, METRICS),
    ]
    if timing:
        parts += ["<h2>Timing</h2>", _table(timing, TIMING)]
    parts.append("<h2>Figures</h2>")
    for fig in _pick_figures(figures):
        data = base64.b64encode(fig.read_bytes()).decode("ascii")
        mime = _MIME[fig.suffix.lower()]
        # A figure in a folder of its own (one per protocol, say) is named with the folder.
        folder, here = fig.parent.resolve(), out.parent.resolve()
        inside = folder != here and folder.is_relative_to(here)
        label = f"{folder.relative_to(here)} — {fig.stem}" if inside else fig.stem
        name = html.escape(label)
        caption = html.escape(FIGURES.get(fig.stem, fig.stem))
        parts.append(
            f"<figure><img alt='{name}' src='data:{mime};base64,{data}'>"
            f"<figcaption><b>{name}</b>: {caption}</figcaption></figure>"
        )
    cfg = json.dumps(config, indent=2, sort_keys=True, default=str)
    parts += ["<h2>Configuration</h2>", f"<pre>{html.escape(cfg)}</pre>", "</body></html>"]
    out.parent.mkdir(parents=True, exist_ok=True)
    write_whole(out, "\n".join(parts))
    return out
