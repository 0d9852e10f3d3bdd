"""The test report a metrologist hands over: one self-contained HTML file (pictures
inline, no script, nothing fetched) that reads on screen and prints to A4.

Sections: the results in the trade's terms (first page), the identification of the
test (machine, set-up, programs with their sha256, what the user said of the
conditions), the plan, per layer the measured radial deviation as a polar plot with
its figures, the geometry in detail, the findings ranked by contribution, the timing
and what stays unexplained; then the definitions of every figure.  Without an analysis
it is the plan's report.  Equal input gives an equal file: no clock is read."""

from __future__ import annotations

import base64
import html
import re

import numpy as np

from ..analyse.sphere import LayerDeviation
from ..plan.files import PlanFiles
from . import report_pictures as pics
from .vocabulary import HEADLINE, effect_name, in_geometry, is_setup, parameter_rows, pooled

#: the report's generator mark: ``report --force`` replaces only a file carrying it
GENERATOR = "sdit-path report"

_CSS = """
@page { size: A4; margin: 13mm 12mm 14mm 12mm; }
* { box-sizing: border-box; }
body { font-family: "DejaVu Sans", "Liberation Sans", Arial, sans-serif; font-size: 9.5pt;
       color: #111; max-width: 186mm; margin: 8mm auto; line-height: 1.35; }
h1 { font-size: 16pt; margin: 0 0 2mm 0; }
h2 { font-size: 12pt; border-bottom: 1.2px solid #777; margin: 6mm 0 2mm 0;
     break-after: avoid; page-break-after: avoid; }
h3 { font-size: 10pt; margin: 4mm 0 1mm 0; break-after: avoid; page-break-after: avoid; }
p { margin: 1mm 0 2mm 0; }
table { border-collapse: collapse; width: 100%; font-size: 8.3pt; margin: 1mm 0 3mm 0; }
tr { break-inside: avoid; page-break-inside: avoid; }
th, td { border-bottom: 0.6px solid #ccc; padding: 1.4px 4px; text-align: left;
         vertical-align: top; }
th { background: #eef1f5; font-weight: 600; }
table.results td:first-child { white-space: nowrap; }
td.n { text-align: right; white-space: nowrap; font-variant-numeric: tabular-nums; }
code, .mono { font-family: "DejaVu Sans Mono", monospace; font-size: 7.6pt;
              word-break: break-all; }
figure { margin: 1mm 0 3mm 0; break-inside: avoid; page-break-inside: avoid; }
figcaption { font-size: 7.8pt; color: #444; }
img { max-width: 100%; height: auto; display: block; }
.grid { display: grid; grid-template-columns: 1fr 1fr; gap: 2mm 5mm; }
.cell { break-inside: avoid; page-break-inside: avoid; }
.small { font-size: 8pt; color: #333; }
.box { border: 1px solid #999; padding: 2mm 3mm; margin: 2mm 0 3mm 0; }
.warn { border-left: 3px solid #c00000; padding-left: 2mm; }
.newpage { break-before: page; page-break-before: always; }
.finding { display: grid; grid-template-columns: 1fr 44mm; gap: 3mm;
           break-inside: avoid; page-break-inside: avoid; border-bottom: 0.6px solid #ccc;
           padding: 1mm 0 2mm 0; }
"""


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _img(png: bytes, alt: str, caption: str = "", width: str = "100%") -> str:
    data = base64.b64encode(png).decode("ascii")
    cap = f"<figcaption>{_e(caption)}</figcaption>" if caption else ""
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{_e(alt)}" '
            f'style="width:{width}">{cap}</figure>')


def _table(head: list[str], rows: list[list[str]], numeric: set[int] = frozenset(),
           css: str = "") -> str:
    h = "".join(f"<th>{x}</th>" for x in head)
    body = []
    for r in rows:
        cells = "".join(f'<td class="n">{c}</td>' if k in numeric else f"<td>{c}</td>"
                        for k, c in enumerate(r))
        body.append(f"<tr>{cells}</tr>")
    cls = f' class="{css}"' if css else ""
    thead = f"<thead><tr>{h}</tr></thead>" if any(head) else ""
    return f"<table{cls}>{thead}<tbody>{''.join(body)}</tbody></table>"


def _f(v, digits: int = 2) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def _pm(value, std, digits: int = 2) -> str:
    """value +- expanded uncertainty (k=2)."""
    if value is None:
        return "-"
    if std is None:
        return f"{value:.{digits}f}"
    return f"{value:+.{digits}f} ± {2 * std:.{digits}f}"


def _digits(std) -> int:
    """Decimals that show the expanded uncertainty to two significant digits (0-4)."""
    if not std or std <= 0:
        return 2
    import math

    return max(0, min(4, 1 - int(math.floor(math.log10(2 * std)))))


def report_html(plan: PlanFiles, plan_sha256: str, analysis: dict | None = None,
                deviations: dict[str, LayerDeviation] | None = None,
                conditions: list[tuple[str, str]] | None = None) -> str:
    """The report.  ``plan_sha256``: of the plan's plan.json; ``analysis``: analyse's
    JSON or None (the plan's report); ``deviations``: per program, the layer's radial
    deviation read from its aligned recording; ``conditions``: (what, value) the user
    gave (operator, instrument, temperatures, date), shown as given."""
    deviations = deviations or {}
    conditions = conditions or []
    m = plan.manifest
    cfg = plan.config
    title = f"Spatial ballbar test: {m.get('machine', cfg.machine.name)}"
    parts = [f"<h1>{_e(title)}</h1>"]
    kind = ("test report: the plan, the recordings and what they determine" if analysis
            else "plan report: the test as planned (no recordings analysed)")
    parts.append(f'<p class="small">sdit-path {kind}. Every ± in this report is an '
                 f"expanded uncertainty (k=2, about 95 % coverage) unless it says k=1; "
                 f"the figures are defined at the end.</p>")
    if analysis:
        parts.append(_summary(analysis))
    parts.append(_identification(plan, plan_sha256, analysis, conditions))
    parts.append(_plan_section(plan))
    if analysis:
        parts.append(_layers(analysis, deviations))
        parts.append(_geometry(analysis))
        parts.append(_findings(plan, analysis))
        parts.append(_timing(analysis))
        parts.append(_unexplained(analysis))
    parts.append(_definitions(bool(analysis)))
    body = "\n".join(parts)
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n"
            f'<meta name="generator" content="{GENERATOR}">\n'
            '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
            f"<title>{_e(title)}</title>\n<style>{_CSS}</style></head>\n<body>\n{body}\n"
            "</body></html>\n")


# -- the results on the first page ---------------------------------------------------


def _summary(a: dict) -> str:
    g = a["geometry"]
    rows = []
    for f in g.get("figures", ()):
        if f["determined"]:
            d = _digits(f["std"])
            rows.append([_e(f["name"]), _pm(f["estimate"], f["std"], d), _e(f["unit"]),
                         _e(f["meaning"])])
        else:
            needs = ", ".join(f.get("needs", ())) or "errors they do not see"
            rows.append([_e(f["name"]), "not determined", _e(f["unit"]),
                         _e(f"these recordings do not separate it from {needs}")])
    across = a.get("across_recordings", {})
    n_rec = len(a["recordings"])
    options = g.get("model", {}).get("options", {})
    for effect in HEADLINE:
        hits = across.get(effect)
        if not hits:
            rows.append([_e(effect_name(effect)), "not found", "",
                         _e(f"in none of the {n_rec} recordings above its noise")])
            continue
        rows += _pooled_rows(effect, hits, n_rec)
    for effect, hits in across.items():
        if is_setup(effect) or effect in HEADLINE or in_geometry(effect, options):
            continue
        rows += _pooled_rows(effect, hits, n_rec)
    out = ['<h2>Results</h2>',
           '<p>What the recordings determine about the machine, in the usual units, each '
           'with its expanded uncertainty (k=2). Squareness and scale mismatch are the '
           'tool\'s motion relative to the table as a ballbar reads it, over the whole '
           'tested hemisphere, estimated together with the dynamic effects below; a dynamic '
           'effect found in several layers is their weighted mean.</p>',
           _table(["quantity", "value ± U (k=2)", "unit", "what it is"], rows, {1},
                  "results")]
    unexpl = [r for r in a["recordings"] if r["diagnosis"]["unexplained"]["significant"]]
    noise = [r["diagnosis"]["noise_um"] for r in a["recordings"]]
    verdict = (f"{len(unexpl)} of {n_rec} recordings hold a reading the library does not "
               f"explain (see <i>What stays unexplained</i>)." if unexpl else
               f"Every recording is explained to its noise ({min(noise):.2f} to "
               f"{max(noise):.2f} um RMS).")
    warn = "".join(f'<p class="warn">{_e(w)}</p>' for w in a.get("warnings", ()))
    return "\n".join(out) + f"<p>{verdict}</p>" + warn


def _pooled_rows(effect: str, hits: list[dict], n_rec: int) -> list[list[str]]:
    rows = []
    progs = ", ".join(h["program"] for h in hits)
    for p in pooled(hits, effect):
        name = f"{effect_name(effect)}: {p['label']}"
        if p["value"] is not None:
            d = _digits(p["std"])
            val = _pm(p["value"], p["std"], d)
            what = (f"found in {p['n']} of {n_rec} recordings ({progs})"
                    + (f"; the layers scatter {p['birge']:.1f} times their own uncertainty, "
                       f"which is raised by that" if p["birge"] and p["birge"] > 1.05 else ""))
        else:
            val = (f"{p['low']:.3g}" if p["low"] == p["high"] else
                   f"{p['low']:.3g} to {p['high']:.3g}")
            what = f"read off the search grid in {p['n']} recordings, no uncertainty"
        if p["note"]:
            what += f"; {p['note']}"
        rows.append([_e(name), val, _e(p["unit"]), _e(what)])
    return rows


# -- what was tested --------------------------------------------------------------------


def _identification(plan: PlanFiles, plan_sha256: str, a: dict | None,
                    conditions: list[tuple[str, str]]) -> str:
    cfg = plan.config
    m = plan.manifest
    test = m.get("test", {})
    rows = [["machine", _e(m.get("machine", cfg.machine.name))],
            ["controller the programs ran on", _e(plan.ran_on or "-")],
            ["bar length", f"{cfg.ballbar.bar_length_mm:g} mm"],
            ["pivot (table frame, work offset "
             f"{_e(m.get('frame', {}).get('work_offset', 'G54'))})",
             ", ".join(f"{v:g}" for v in cfg.ballbar.pivot_mm) + " mm"],
            ["tool length (to the spindle ball's centre)", f"{cfg.machine.tool_length_mm:g} mm"],
            ["feed", f"{test.get('feed_mm_per_min', cfg.test.feed_mm_per_min):g} mm/min"],
            ["dwell at each static node", f"{test.get('dwell_s', cfg.test.dwell_s):g} s"],
            ["plan (plan.json sha256)", f'<span class="mono">{_e(plan_sha256)}</span>'],
            ["configuration", f"{_e(m.get('config', {}).get('file', 'config.toml'))} "
             f'<span class="mono">{_e(m.get("config", {}).get("sha256", ""))}</span>']]
    for what, value in conditions:
        rows.append([_e(what), _e(value)])
    if a:
        for r in a["recordings"]:
            header = r.get("header") or {}
            said = "; ".join(f"{k}: {v}" for k, v in header.items()
                             if k not in ("program", "sample_rate_hz", "source"))
            rows.append([f"recording of {_e(r['program'])}",
                         f"{_e(r['file'])}" + (f" ({_e(said)})" if said else "")])
    progs = [p for p in m.get("programs", ()) if p.get("controller") == plan.ran_on]
    prow = [[_e(p["file"]), f"{p.get('blocks', 0)}", _f(p.get("cycle_time_s"), 1),
             f'<span class="mono">{_e(p.get("sha256", ""))}</span>'] for p in progs]
    for p in m.get("master_programs", ()):
        if p.get("controller") == plan.ran_on:
            prow.append([_e(p["file"]), f"{p.get('blocks', 0)}", "-",
                         f'<span class="mono">{_e(p.get("sha256", ""))}</span>'])
    return ("<h2>The test</h2>" + _table(["", ""], rows)
            + "<h3>Programs</h3>"
            + _table(["file", "blocks", "cycle (s)", "sha256"], prow, {1, 2}))


def _plan_section(plan: PlanFiles) -> str:
    m = plan.manifest
    progs = {p["layer"]: p for p in m.get("programs", ())
             if p.get("controller") == plan.ran_on and "layer" in p}
    segs = {s["id"]: s for s in m.get("segments", ())}
    layers = []
    rows = []
    for lay in m.get("layers", ()):
        p = progs.get(lay["name"])
        if p is None:
            continue
        layers.append((lay["name"], plan.trajectory(p["name"])))
        own = [segs[s] for s in lay["segments"] if s in segs]
        clear = [s["check"]["min_clearance_mm"] for s in own
                 if s.get("check", {}).get("min_clearance_mm") is not None]
        omitted = ", ".join(str(o) if not isinstance(o, dict) else
                            str(o.get("id", o)) for o in lay.get("omitted", ())) or "none"
        el = lay.get("elevation_deg", [0, 0])
        rows.append([_e(lay["name"]), _e(p["name"]), f"{el[0]:g} to {el[1]:g}",
                     f"{len(own)}", _f(p.get("cycle_time_s"), 1),
                     _f(min(clear) if clear else None, 1),
                     f"{p.get('max_radial_deviation_um', 0):.3f}", _e(omitted)])
    starts = {p["name"]: p.get("start_node", "") for p in progs.values()}
    picture = pics.plan_map(layers, list(m.get("nodes", ())), plan.config.ballbar.pivot_mm,
                            starts)
    setup = _machine_at_start(plan, layers)
    return ('<h2 class="newpage">The plan</h2>'
            + _img(picture, "the test seen from above the pivot",
                   "Each layer runs its segments forward (the arrow) from its start node, "
                   "then back in reverse, with a dwell at every static node. Grey dashed: "
                   "the transits between layers. Node names: track and number.", "84%")
            + _table(["layer", "program", "elevation (deg)", "segments", "cycle (s)",
                      "min clearance (mm)", "max radial deviation as written (um)",
                      "omitted"], rows, {3, 4, 5, 6})
            + setup)


def _machine_at_start(plan: PlanFiles, layers: list) -> str:
    """The machine's parts, the balls and the bar where the first layer starts."""
    if not layers:
        return ""
    from ..interference.scene import Scene
    from ..machine.kinematics import Kinematics
    from ..timing.trajectory import axis_values_rad

    name, traj = layers[0]
    kin = Kinematics(plan.config.machine)
    q = axis_values_rad(traj, kin)[:1]
    scene = Scene(plan.config, kin)
    poses = scene.part_poses(q)
    rot_w, trans_w = kin.table_transform(q)
    pivot_bed = rot_w[0] @ np.asarray(plan.config.ballbar.pivot_mm, float) + trans_w[0]
    meshes = [p.name for p in scene.parts if p.shape == "mesh"]
    png = pics.machine_view(scene.parts, poses, pivot_bed, plan.config.ballbar.bar_length_mm,
                            f"The set-up where layer {name} starts (bed frame)")
    note = (f" Mesh parts ({', '.join(meshes)}) are not drawn." if meshes else "")
    return _img(png, "the machine at the start", "The machine's parts as the interference check "
                "knows them (table side blue, tool side grey), the balls and the bar (orange) "
                "where the first layer starts; dashed: the sphere the tool ball runs on." + note,
                "80%")


# -- the measurement ------------------------------------------------------------------------


def _layers(a: dict, deviations: dict[str, LayerDeviation]) -> str:
    cells, rows = [], []
    for r in a["recordings"]:
        d = deviations.get(r["program"])
        if d is None:
            continue
        cells.append(f'<div class="cell">{_img(pics.polar(d), f"polar plot {d.program}")}</div>')
        rows.append([_e(d.program), _f(d.max_um), _f(d.min_um), _f(d.range_um),
                     _f(d.hysteresis_um), _f(d.hysteresis_median_um),
                     f"{r['diagnosis']['noise_um']:.2f}"])
    if not cells:
        return ""
    return ('<h2 class="newpage">Radial deviation per layer</h2>'
            '<p>The bar reading along each layer against the azimuth, magnified (the bold '
            'circle is the sphere; the scale reads in um), forward pass in blue, reverse in '
            'orange, with the ball centring and bar length offset removed (least squares '
            'over the layer). The reading includes the dynamics: a servo mismatch opens the '
            'forward and reverse passes apart, a backlash steps at the reversals.</p>'
            f'<div class="grid">{"".join(cells)}</div>'
            + _table(["layer", "max (um)", "min (um)", "sphericity range (um)",
                      "hysteresis max (um)", "hysteresis median (um)", "noise (um, k=1)"],
                     rows, {1, 2, 3, 4, 5, 6}))


def _geometry(a: dict) -> str:
    g = a["geometry"]
    out = ['<h2 class="newpage">Geometry in detail</h2>',
           f"<p>The model holds {g['model']['parameters']} error parameters; the "
           f"{len(a['recordings'])} recordings determine {g['determined']} independent "
           f"combinations of them (the data's rank is {g['rank']}). The figures on the first "
           f"page are read off these combinations; each combination below is a weighted sum "
           f"of ISO 230-1 parameters, with its value and expanded uncertainty (k=2). A "
           f"parameter ending in .P1 is the slope term of an error over the tested travel: "
           f"its value is the error at the positive end of the travel less the centre's (um "
           f"for a translation, urad for a rotation).</p>"]
    rows = []
    for k, c in enumerate(g["combinations"], start=1):
        terms = sorted(c["terms"], key=lambda t: -abs(t["typical_contribution"]))
        lead = " + ".join(f"{t['coefficient']:.3g}·{_e(t['parameter'])}"
                          for t in terms[:4]).replace("+ -", "− ")
        more = f" + {len(terms) - 4} smaller terms" if len(terms) > 4 else ""
        d = _digits(c["std"])
        rows.append([f"{k}", lead + more, _pm(c["estimate"], c["std"], d), _e(c["unit"]),
                     _e(gloss(terms))])
    out.append(_table(["", "combination (leading terms)", "value ± U (k=2)", "unit",
                       "what it reads"], rows, {2}))
    ind = g.get("identifiable_parameters", ())
    if ind:
        out.append("<h3>Parameters determined one by one</h3>")
        out.append(_table(["parameter", "value ± U (k=2)", "unit", "what it is"],
                          [[_e(d["parameter"]), _pm(d["estimate"], d["std"], _digits(d["std"])),
                            _e(d["unit"]), _e(parameter_words(d["parameter"]))]
                           for d in ind], {1}))
    na = g.get("not_individually_identifiable", ())
    if na:
        out.append(f"<h3>Not determined ({len(na)} parameters)</h3><p>These recordings see "
                   f"them only inside the combinations above: {_e(', '.join(na))}. "
                   f"<code>sdit-path identify --plan P --trace ... --ask NAME</code> names the "
                   f"additional set-up (another pivot height, another tool length, the rotary "
                   f"axes moving) that would determine NAME, simulated on the same path.</p>")
    for asked in g.get("asked", ()) or ():
        if asked.get("identifiable"):
            continue
        tried = "; ".join(f"{r['set_up']}: " + (f"yes, to ± {2 * r['std']:.3g} (k=2)"
                                                if r["makes_identifiable"] else "no")
                          for r in asked.get("needs", ()))
        out.append(f"<p>{_e(asked['parameter'])}: {tried}</p>")
    nuis = [[_e(r["program"]), ", ".join(f"{v:.2f}" for v in r["nuisances"]["centring_um"]),
             f"{r['nuisances']['bar_length_um']:.2f}"] for r in a["recordings"]]
    out.append("<h3>Set-up of each recording</h3><p>The ball centring and the bar length "
               "offset, estimated with the geometry. The centring also holds the machine's "
               "constant translations (a constant offset of the tool ball from the pivot reads "
               "exactly like it), so it is not the operator's centring alone.</p>"
               + _table(["layer", "ball centring x, y, z (um)", "bar length offset (um)"],
                        nuis, {2}))
    return "\n".join(out)


def _findings(plan: PlanFiles, a: dict) -> str:
    items = []
    for r in a["recordings"]:
        for f in r["diagnosis"]["findings"]:
            if is_setup(f["effect"]):
                continue
            items.append((f["contribution_rms_um"], r, f))
    items.sort(key=lambda x: (-x[0], x[1]["program"], x[2]["effect"]))
    out = ['<h2 class="newpage">Findings, ranked by contribution</h2>',
           "<p>Every effect the diagnosis found beyond the set-up, in every recording, largest "
           "first. <i>Contribution</i>: the RMS of its reading over the recording. "
           "<i>Held out</i>: the RMS on samples of the recording the fit never saw, "
           "before and after the effect is added: a real effect shrinks it. "
           "<i>Confidence</i>: how clearly the data prefer it to its nearest rival.</p>"]
    if not items:
        out.append("<p>None: every recording is explained by the set-up and the geometry.</p>")
    trajectories: dict[str, object] = {}
    for k, (contrib, r, f) in enumerate(items, start=1):
        params = parameter_rows(f["parameters"], f.get("parameter_std", {}), f["effect"])
        plist = "<br>".join(
            f"{_e(p['label'])}: " + (_pm(p["value"], p["std"], _digits(p["std"]))
                                     if p["std"] is not None else f"{p['value']:.4g}")
            + f" {_e(p['unit'])}" + (f' <span class="small">({_e(p["note"])})</span>'
                                     if p["note"] else "")
            for p in params)
        alt = (f"; cannot be told from {', '.join(map(effect_name, f['ambiguous_with']))}: "
               f"{f.get('separate_by', '')}" if f.get("ambiguous_with") else "")
        where = (f.get("where") or {}).get("segments", [])
        text = (f"<b>{k}. {_e(effect_name(f['effect']))}</b> in {_e(r['program'])} "
                f"({_e(r['file'])}): {contrib:.2f} um RMS, {_e(f['confidence'])} confidence; "
                f"held out {f['heldout_rms_before_um']:.3f} → "
                f"{f['heldout_rms_after_um']:.3f} um{_e(alt)}"
                f'<br><span class="small">{_e(f.get("title", ""))}</span><br>{plist}'
                + (f'<br><span class="small">strongest in {_e(", ".join(where[:8]))}</span>'
                   if where else ""))
        prog = r["program"]
        if prog not in trajectories:
            trajectories[prog] = plan.trajectory(prog)
        pic = pics.where_map(trajectories[prog], plan.config.ballbar.pivot_mm, where,
                             f"{prog}: where ({len(where)} segments)")
        out.append(f'<div class="finding"><div>{text}</div><div>'
                   f'{_img(pic, "where the finding lives")}</div></div>')
    return "\n".join(out)


def _timing(a: dict) -> str:
    rows = []
    charts = []
    for r in a["recordings"]:
        al = r["diagnosis"]["alignment"]
        t = r.get("timing") or {"model": "plan"}
        model = {"plan": "the plan's timing; start and clock rate measured",
                 "control": "the control's own planner (LinuxCNC 2.9) on the program as "
                            "written",
                 "recording": "the recording's own, run by run (each run's start and end "
                              "where the reading places them)"}.get(t["model"], t["model"])
        own = t["model"] == "recording"
        clock = ("within each run" if own else
                 _pm(al.get("clock_ppm"), al.get("clock_std_ppm"), 1))
        rows.append([_e(r["program"]), _e(r["file"]),
                     _pm(al["offset_s"], al.get("offset_std_s"), 4), clock, _e(model)])
        runs = t.get("runs") or []
        if runs:
            key = "measured_s" if own else "control_s"
            charts.append(_img(pics.timing_chart(r["program"], runs, key),
                               f"timing {r['program']}"))
    return ('<h2>Timing against the plan</h2><p>Where each program starts in its recording '
            '(s) and the recorder\'s clock rate against the control\'s (ppm), each with its '
            'expanded uncertainty (k=2). A run whose duration differs from the plan is a '
            'finding of its own, never read as a servo effect.</p>'
            + _table(["layer", "recording", "start (s)", "clock (ppm)", "timing read with"],
                     rows, {2, 3}) + "".join(charts))


def _unexplained(a: dict) -> str:
    rows = []
    for r in a["recordings"]:
        d = r["diagnosis"]
        u = d["unexplained"]
        where = ", ".join((u.get("where") or {}).get("segments", [])[:8])
        rows.append([_e(r["program"]), f"{d['gap']['rms_um']:.3f}", f"{u['rms_um']:.3f}",
                     f"{d['noise_um']:.3f}",
                     "not explained by the library" if u["significant"] else "at the noise",
                     _e(where) if u["significant"] else ""])
    return ("<h2>What stays unexplained</h2><p><i>Gap</i>: the RMS of the reading against "
            "the ideal one (the set-up included); <i>left</i>: what remains once the geometry "
            "and every finding are taken out; <i>noise</i>: the recording's own (k=1). What "
            "lies outside the effect library is reported here, with where it lives, never "
            "pinned on a wrong effect.</p>"
            + _table(["layer", "gap (um)", "left (um)", "noise (um)", "verdict", "where"],
                     rows, {1, 2, 3}))


def _definitions(measured: bool) -> str:
    items = [
        ("Expanded uncertainty U (k=2)", "twice the standard uncertainty; the interval "
         "value ± U holds the true value with about 95 % probability when the model "
         "holds. The standard uncertainty is the larger of what the noise gives and the "
         "spread over 1 s blocks of the recordings."),
        ("Max radial deviation as written", "how far the program as written for the "
         "controller leaves the sphere (its chords or spline against the sphere), in um: "
         "every deviation of the path is read by the ballbar as a machine error."),
        ("Min clearance", "the smallest distance between the bar, the balls and the "
         "machine's parts along the layer, as checked by the planner."),
    ]
    if measured:
        items += [
            ("Radial deviation", "the bar reading on the layer's test segments less the "
             "least-squares ball centring and bar length offset (dwells and transits left "
             "out)."),
            ("Max / min", "the extremes of the radial deviation over the layer, both passes."),
            ("Sphericity range", "max less min: ISO 230-4's circular deviation G read over "
             "the layer's band of the sphere."),
            ("Hysteresis", "the difference of the radial deviation between the forward and "
             "the reverse pass at the same point of the same segment (ISO 230-4's circular "
             "hysteresis H): its largest value and its median."),
            ("Squareness X-Y (Y-Z, Z-X)", "the shear of the tool's motion relative to the "
             "table between the two axes, D_xy + D_yx in urad (= um/m): positive when the "
             "angle between the positive axes is less than 90 deg."),
            ("Scale mismatch X-Y (Y-Z)", "the difference of the two axes' scale errors, "
             "tool relative to table, in um/m; the third (Z-X) is minus the sum of the two. "
             "A common scale error of all three axes reads like the bar length and is not "
             "seen by a ballbar."),
            ("Servo mismatch", "the difference of two axes' servo lags (ms): it opens the "
             "forward and reverse passes apart by the lag times the speed."),
            ("Backlash", "the lost motion at an axis' reversal (um)."),
            ("Reversal spike", "a decaying pulse after an axis' reversal (friction): its "
             "height (um) and time constant (ms)."),
            ("Cyclic error", "a ripple locked to an axis' position (scale or screw pitch): "
             "its amplitude (um)."),
        ]
    rows = [[f"<b>{_e(k)}</b>", v] for k, v in items]
    return '<h2 class="newpage">Definitions</h2>' + _table(["figure", "definition"], rows)


# -- words for the ISO parameters -----------------------------------------------------

_ABOUT = {"A": "X", "B": "Y", "C": "Z"}
_SQUARE = {"EC0Y": "squareness of Y to X", "EB0Z": "squareness of Z to X",
           "EA0Z": "squareness of Z to Y"}
_NAME = re.compile(r"^E([XYZABC])([XYZABC])(?:\.(P\d+|T\d+|[cs]\d+))?$")
_LOCATION = re.compile(r"^E([XYZABC])0([ABC])$")


def parameter_words(name: str) -> str:
    """An ISO 230-1/-7 parameter name in words (EXY.P1: straightness of Y in X, slope)."""
    if name in _SQUARE:
        return _SQUARE[name]
    loc = _LOCATION.match(name)
    if loc:
        c, axis = loc.groups()
        return (f"position of the {axis} axis in {c}" if c in "XYZ" else
                f"tilt of the {axis} axis about {_ABOUT[c]}")
    mm = _NAME.match(name)
    if not mm:
        return name
    c, axis, basis = mm.groups()
    if c in "XYZ":
        what = f"positioning of {axis}" if c == axis else f"straightness of {axis} in {c}"
    else:
        what = f"rotation of {axis} about {_ABOUT[c]}"
    if basis is None:
        return f"{what} (constant)"
    if basis == "P1":
        return f"{what}, slope over the travel"
    if basis.startswith("P"):
        return f"{what}, Legendre degree {basis[1:]}"
    if basis.startswith("T"):
        return f"{what}, table node {basis[1:]}"
    return f"{what}, harmonic {basis[1:]} ({'cos' if basis[0] == 'c' else 'sin'})"


def gloss(terms: list[dict]) -> str:
    """A combination in one line: its leading terms in words."""
    lead = [t for t in terms if abs(t["typical_contribution"])
            >= 0.2 * abs(terms[0]["typical_contribution"])][:3] if terms else []
    return "; ".join(parameter_words(t["parameter"]) for t in lead)
