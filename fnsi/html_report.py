"""One-page HTML reports of an identification, a distortion analysis and a study.

A report is a single self-contained HTML file: its tables are text and its figures are
the PNG artefacts embedded as ``data:`` URIs, so it opens offline, can be mailed or
archived alone, and prints (one column, figures never split across pages). It needs
nothing but a browser: no script, no stylesheet or font from elsewhere.

The builders take the JSON documents the library already writes (``result.json``,
``analysis.json``, ``study.json``, ``diagnosis.json``) and the figures as bytes, so the
CLI (from its folders) and the service (from its stored artefacts) render the same page.
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

REPORT_NAME = "report.html"
"""File name of a report among an identification's or an analysis's artefacts."""

# Print: one column, no figure or table row split over two pages.
_STYLE = """
body { font-family: sans-serif; margin: 1.5em auto; max-width: 60em; color: #111; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; border-bottom: 1px solid #999; }
table { border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.5em; text-align: right; }
th { background: #eee; } td.text { text-align: left; }
figure { margin: 1em 0; page-break-inside: avoid; break-inside: avoid; }
figure img { max-width: 100%; height: auto; }
p.warning { color: #a00; } p.note { color: #444; font-style: italic; }
tr { page-break-inside: avoid; break-inside: avoid; }
@media print { body { margin: 0; max-width: none; } h2 { page-break-after: avoid; } }
"""


@dataclass(frozen=True)
class Table:
    """A table of text cells; numbers right-aligned, words left-aligned."""

    headers: Sequence[str]
    rows: Sequence[Sequence[Any]]


@dataclass(frozen=True)
class Section:
    """A heading with, in this order, paragraphs, warnings, notes, tables and figures.

    ``figures`` maps a caption (usually the artefact name) to PNG bytes.
    """

    heading: str
    paragraphs: Sequence[str] = ()
    warnings: Sequence[str] = ()
    notes: Sequence[str] = ()
    tables: Sequence[Table] = ()
    figures: Mapping[str, bytes] = field(default_factory=dict)


def render_page(title: str, sections: Sequence[Section]) -> bytes:
    """The self-contained HTML page (UTF-8 bytes) of ``sections`` under ``title``."""
    body = "\n".join(_section(s) for s in sections)
    return (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head>\n"
            f"<body><h1>{html.escape(title)}</h1>\n{body}\n</body></html>\n").encode()


def _section(section: Section) -> str:
    parts = [f"<section><h2>{html.escape(section.heading)}</h2>"]
    parts += [f"<p>{html.escape(p)}</p>" for p in section.paragraphs]
    parts += [f"<p class=\"warning\">Warning: {html.escape(w)}</p>" for w in section.warnings]
    parts += [f"<p class=\"note\">Note: {html.escape(n)}</p>" for n in section.notes]
    parts += [_table(t) for t in section.tables]
    parts += [_figure(caption, png) for caption, png in section.figures.items()]
    return "\n".join(parts) + "</section>"


def _table(table: Table) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in table.headers)
    rows = "".join("<tr>" + "".join(_cell(v) for v in row) + "</tr>" for row in table.rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>"


def _cell(value: Any) -> str:
    text = cell_text(value)
    numeric = isinstance(value, int | float) and not isinstance(value, bool)
    return f"<td>{text}</td>" if numeric else f"<td class=\"text\">{text}</td>"


def cell_text(value: Any) -> str:
    """A value as table text: 4 significant digits, '-' for missing or non-finite."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    if isinstance(value, float):
        return html.escape(f"{value:.4g}")
    if isinstance(value, list | tuple):
        return html.escape(", ".join(str(v) for v in value)) or "-"
    return html.escape(str(value))


def _figure(caption: str, png: bytes) -> str:
    uri = "data:image/png;base64," + base64.b64encode(png).decode("ascii")
    return (f"<figure><img src=\"{uri}\" alt=\"{html.escape(caption)}\">"
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _pngs(figures: Mapping[str, bytes]) -> dict[str, bytes]:
    return {name: content for name, content in figures.items() if name.endswith(".png")}


# -- identification ------------------------------------------------------------------------
def identification_page(document: Mapping[str, Any], figures: Mapping[str, bytes], *,
                        title: str = "FNSI identification") -> bytes:
    """Report of an identification: modes, coefficients, errors, warnings and figures.

    Parameters
    ----------
    document : mapping
        ``result.json`` (:func:`fnsi.report.identification_report`).
    figures : mapping of str to bytes
        Artefacts by name; every ``.png`` among them is embedded.
    """
    modes = Table(["mode", "frequency [Hz]", "damping ratio [%]", "confirmed"],
                  [[k + 1, m["frequency_hz"], 100 * m["damping_ratio"],
                    "-" if m.get("confirmed") is None else ("yes" if m["confirmed"] else "no")]
                   for k, m in enumerate(document["modes"])])
    coefficients = Table(
        ["coefficient", "mean Re", "log10(Re/Im)", "identifiable / reason"],
        [[c["name"], c.get("mean_real"), c.get("log10_real_imag"),
          "yes" if c.get("mean_real") is not None else c.get("reason")]
         for c in document["coefficients"]])
    sections = [Section(f"Model of order {document['order']}", warnings=document["warnings"],
                        tables=[modes] + ([coefficients] if document["coefficients"] else []))]
    for kind, errors in document.get("errors", {}).items():
        sections.append(_errors_section(kind, errors))
    sections.append(Section("Figures", figures=_pngs(figures)))
    return render_page(title, sections)


def _offsets_sentence(offsets: Mapping[str, Any], data: str) -> str:
    """:func:`fnsi.offsets.describe` as a sentence (channel names keep their case)."""
    from fnsi.offsets import describe  # numerical imports: not for the CLI's start-up

    text = describe(offsets, data)
    return f"{text[:1].upper()}{text[1:]}."


def _errors_section(kind: str, errors: Mapping[str, Any]) -> Section:
    heading = f"Simulation errors on the {kind} data"
    if "failure" in errors:
        return Section(heading, warnings=[f"the model could not be simulated: "
                                          f"{errors['failure']}"])
    overall = (f"Overall NRMSE {cell_text(errors['overall_nrmse_percent'])} % against a "
               f"noise floor of {cell_text(errors['overall_noise_floor_percent'])} %.")
    offsets = [_offsets_sentence(errors["offsets"], kind)] if "offsets" in errors else []
    return Section(heading, paragraphs=[overall, *offsets], tables=[_errors_table(errors)])


def _errors_table(errors: Mapping[str, Any]) -> Table:
    """NRMSE and noise floor per output (:meth:`fnsi.errors.ModelErrors.to_json`)."""
    return Table(["output", "NRMSE [%]", "noise floor [%]"],
                 [[c["output"], c["nrmse_percent"], c["noise_floor_percent"]]
                  for c in errors["channels"]])


# -- distortion analysis -------------------------------------------------------------------
def analysis_page(document: Mapping[str, Any], figures: Mapping[str, bytes], *,
                  title: str = "Nonlinear distortion analysis") -> bytes:
    """Report of a distortion analysis: the verdict, levels per output, the figure.

    Parameters
    ----------
    document : mapping
        ``analysis.json`` (:meth:`fnsi.distortion.DistortionAnalysis.to_json`).
    figures : mapping of str to bytes
        Artefacts by name; every ``.png`` among them is embedded.
    """
    groups = ("excited", "odd", "even", "above_band")
    table = Table(["output"] + [f"{g.replace('_', ' ')} [dB over noise]" for g in groups],
                  [[c["name"]] + [_level(c[g]) for g in groups] for c in document["channels"]])
    low, high = document["band_hz"]
    design = (f"Band {low:g}-{high:g} Hz, {document['realisations']} realisation(s) of "
              f"{document['periods']} periods, "
              f"{'odd' if document['odd_design'] else 'full'} multisine design. "
              "A * marks a level above the noise.")
    return render_page(title, [
        Section("Verdict", paragraphs=[document["verdict"]]),
        Section("Distortion levels", paragraphs=[design], tables=[table]),
        Section("Figures", figures=_pngs(figures))])


def _level(group: Mapping[str, Any]) -> str:
    if not group["lines"]:
        return "-"
    return f"{group['level_db']:.1f}{'*' if group['above_noise'] else ''}"


# -- study ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class DiagnosisPart:
    """A diagnosis of a study for its report: ``diagnosis.json`` and its figures."""

    document: Mapping[str, Any]
    figures: Mapping[str, bytes]


def study_page(study: Mapping[str, Any], figures: Mapping[str, bytes],
               diagnoses: Sequence[DiagnosisPart] = ()) -> bytes:
    """Report of a modelling study: error history, each revision, each diagnosis.

    Parameters
    ----------
    study : mapping
        ``study.json`` (:meth:`fnsi.study.Study.to_json`).
    figures : mapping of str to bytes
        The study's figures by artefact name (``history.png``, ``revision-<n>-*.png``):
        each revision's are shown in its section, the others under the history.
    diagnoses : sequence of DiagnosisPart
    """
    history = Table(["revision", "order", "NRMSE [%]", "noise floor [%]", "elements", "change",
                     "failure"],
                    [[r["number"], r["order"],
                      "failed" if r["nrmse_percent"] is None else r["nrmse_percent"],
                      r["noise_floor_percent"], r["elements"], r["note"], r["failure"]]
                     for r in study["history"]])
    prefixes = tuple(f"revision-{r['number']}-" for r in study["revisions"])
    general = {n: c for n, c in _pngs(figures).items() if not n.startswith(prefixes)}
    offsets = study["validation"].get("offsets")
    sections = [Section("Error history on the validation data", tables=[history],
                        figures=general, warnings=study.get("warnings", []),
                        paragraphs=[_offsets_sentence(offsets, "validation")]
                        if offsets else [])]
    sections += [_revision_section(r, figures) for r in study["revisions"]]
    sections += [_diagnosis_section(d) for d in diagnoses]
    name = study.get("name") or "unnamed"
    return render_page(f"FNSI modelling study: {name}", sections)


def _revision_section(revision: Mapping[str, Any], figures: Mapping[str, bytes]) -> Section:
    number = revision["number"]
    modes = Table(["mode", "frequency [Hz]", "damping ratio [%]"],
                  [[k + 1, f, 100 * z] for k, (f, z) in enumerate(zip(
                      revision["modal"]["frequency_hz"], revision["modal"]["damping_ratio"],
                      strict=True))])
    coefficients = Table(["coefficient", "mean Re", "log10(Re/Im)"],
                         [[c["name"], c.get("mean_real"), c.get("log10_real_imag")]
                          for c in revision["coefficients"]])
    tables = [modes] + ([coefficients] if revision["coefficients"] else [])
    if revision["validation"] is not None:
        tables.append(_errors_table(revision["validation"]))
    failure = [f"the model could not be simulated: {revision['failure']}"] \
        if revision["failure"] else []
    concerns = [s["concern"] for s in revision.get("separability", []) if s.get("concern")]
    own = {n: c for n, c in _pngs(figures).items() if n.startswith(f"revision-{number}-")}
    return Section(f"Revision {number}: {revision['note']} (order "
                   f"{revision['identified_order']})", warnings=failure + concerns,
                   tables=tables, figures=own)


def _diagnosis_section(part: DiagnosisPart) -> Section:
    doc = part.document
    candidates = Table(
        ["rank", "effect", "validation NRMSE [%]", "better by", "beats noise floor",
         "explanation"],
        [[k + 1, c["effect"], c["validation_nrmse_percent"], c["error_reduction_factor"],
          "yes" if c["beats_noise_floor"] else "no",
          c["explanation"] + (f" Failed: {c['failure']}" if c.get("failure") else "")
          + (f" Implausible: {c['concern']}" if c.get("concern") else "")]
         for k, c in enumerate(doc["candidates"])])
    return Section(f"Diagnosis of revision {doc['revision']}", paragraphs=[doc["summary"]],
                   notes=doc.get("notes", []), tables=[candidates],
                   figures={n: c for n, c in _pngs(part.figures).items()
                            if n != "history.png"})
