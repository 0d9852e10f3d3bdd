"""The identification report in plain words."""

from __future__ import annotations

import textwrap

from ..geometry.hemisphere import TEST_SEGMENT


def summary_text(report: dict, max_combinations: int = 20, setup: bool = True) -> str:
    """The identification in words; ``setup=False`` leaves the set-up (centring, bar
    length) to the caller, which reports it once with its recording."""
    lines = []
    m = report["model"]
    lines.append(f"Identification from {report['samples']} samples of "
                 f"{len(report['experiments'])} trace(s): noise about "
                 f"{report['noise_std_um']:.3f} um, residual RMS {report['residual_rms_um']:.3f} um.")
    lines.append(f"Model: {m['parameters']} parameters ({_options(m['options'])}), plus ball "
                 f"centring (3) and bar length (1) for every trace, which are always unknown.")
    for r in report.get("recordings", []):
        lines.append(f"  {r['file']}: aligned to {r['program']}, start {r['offset_s']:.4f} +- "
                     f"{r['offset_std_s'] * 1e3:.1f} ms, clock {r['clock_ppm']:+.1f} +- "
                     f"{r['clock_std_ppm']:.1f} ppm, residual {r['residual_rms_um']:.2f} um "
                     f"(noise {r['noise_um']:.2f} um), {r['samples_in_program']} samples in the "
                     f"program")
    warnings = report.get("warnings", [])
    for w in warnings:
        lines.append(f"WARNING: {w}")
    lines.append("")
    if warnings:
        lines.append("The numbers below come from recordings with the warnings above: they are "
                     "what the model makes of them, not established machine errors.")
    lines.append(f"What the data determine: {report['determined']} independent combination(s) "
                 f"(structural rank {report['rank']}; a combination counts as determined when its "
                 f"standard uncertainty is below half a typical error; uncertainties are the "
                 f"larger of the noise's and the spread over 1 s blocks of the recordings, which "
                 f"holds for what the model lacks within a second). Every +- below is one "
                 f"standard uncertainty (k=1); the expanded uncertainty (k=2, about 95 % "
                 f"coverage) is twice it.")
    for k, c in enumerate(report["combinations"][:max_combinations], start=1):
        lines.append(f"  {k:2d}. {c['text']}")
    if len(report["combinations"]) > max_combinations:
        lines.append(f"  ... and {len(report['combinations']) - max_combinations} more (see --json)")
    lines += figures_lines(report.get("figures", ()))
    ind = report["identifiable_parameters"]
    if ind:
        lines.append("Parameters determined individually:")
        for d in ind:
            lines.append(f"  {d['parameter']} = {d['estimate']:.3f} +- {d['std']:.3f} {d['unit']}")
    else:
        lines.append("No single ISO parameter is determined individually: the data see only "
                     "the combinations above.")
    na = report["not_individually_identifiable"]
    # every one of them, wrapped: a list cut short hides the one a reader looks for
    lines += textwrap.wrap(f"Not determined individually ({len(na)}): {', '.join(na)}.", 88,
                           subsequent_indent="  ", break_on_hyphens=False)
    if setup:
        lines += _setup_lines(report)
    if "prior_estimates" in report:
        lines.append("")
        lines.append("Every parameter under a prior (Tikhonov; each ~ a typical error). "
                     "'prior-driven' numbers are the prior speaking, not the machine:")
        for d in report["prior_estimates"]:
            lines.append(f"  {d['parameter']:>10} = {d['estimate']:9.3f} +- {d['std']:7.3f} "
                         f"{d['unit']:<4}  resolution {d['resolution']:.2f}  {d['label']}")
    for a in report.get("asked", []):
        lines.append("")
        if a["identifiable"]:
            lines.append(f"{a['parameter']}: determined by these data (see above).")
            continue
        lines.append(f"{a['parameter']}: not identifiable from these data. Adding one more set-up "
                     f"(simulated on the same path):")
        for r in a["needs"]:
            verdict = (f"yes, to +- {r['std']:.3f}" if r["makes_identifiable"] else
                       f"no ({r['share_in_determined_space']:.0%} of it would be seen)")
            lines.append(f"  {r['set_up']}: {verdict}")
    obs = report["observability"]
    if obs["layers"]:
        lines.append("")
        lines.append("Observability of the determined combinations (O1 larger is better; O4 is "
                     "the noise amplification index, larger is better):")
        for k, v in obs["layers"].items():
            lines.append(f"  {k}: O1 {v['O1']:.3g}, O4 {v['O4']:.3g}")
        # the test segments (A1-2, D3-2, ...), not the transits between nodes that every
        # layer must run (A-1>B-1, E-1>TOP), which see little of the geometry by design
        segs = sorted(((k, v) for k, v in obs["segments"].items() if TEST_SEGMENT.match(k)),
                      key=lambda kv: kv[1]["O4"])
        if segs:
            worst = ", ".join(f"{k} (O4 {v['O4']:.2g})" for k, v in segs[:5])
            lines.append(f"  weakest test segments: {worst}")
    return "\n".join(lines)


def _setup_lines(report: dict) -> list[str]:
    lines = ["", "Set-up (estimated, not machine errors). The ball centring also absorbs the "
                 "machine's constant translations: a constant offset between the tool ball and "
                 "the pivot, as seen from the table, reads exactly as a centring error, so "
                 "these are not the operator's centring alone:"]
    for n in report["nuisances"]:
        c = n["centring_um"]
        lines.append(f"  {n['program']}: ball centring ({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}) um, "
                     f"bar length offset {n['bar_length_um']:.2f} um")
    return lines


def figures_lines(figures) -> list[str]:
    """Squareness and scale mismatch as a ballbar reads them, with their expanded
    uncertainty (k=2); those the data do not determine, with what they would need."""
    if not figures:
        return []
    out = ["In the trade's terms (the tool's motion relative to the table, as a ballbar reads "
           "it; +- is the expanded uncertainty, k=2):"]
    for f in figures:
        if f["determined"]:
            out.append(f"  {f['name']:<20} {f['estimate']:+9.2f} +- {2 * f['std']:.2f} "
                       f"{f['unit']:<5} {f['meaning']}")
        else:
            out.append(f"  {f['name']:<20} not determined: it depends on "
                       f"{', '.join(f['needs']) or 'parameters'} beyond what the data see")
    return out


def _options(o: dict) -> str:
    parts = [f"linear {o['linear_basis']} order {o['linear_order']}",
             f"rotary Fourier order {o['rotary_order']}"]
    parts.append("squareness" if o["squareness"] else "no squareness")
    parts.append("location errors" if o["location"] else "no location errors")
    return ", ".join(parts)
