"""Command line: ``sdit-path plan [CONFIG] --out DIR``.

User mistakes end with one line on stderr and a non-zero exit code (see
:mod:`sdit_path.errors`); progress is shown only here, never in the library.
"""

from __future__ import annotations

import sys

import click
import numpy as np
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from . import __version__
from .errors import SditError


def _fail(exc: SditError) -> None:
    click.echo(f"sdit-path: error: {exc}", err=True)
    for line in getattr(exc, "details", []):
        click.echo(f"  {line}", err=True)
    sys.exit(exc.exit_code)


class _Steps:
    """Progress of a long command on stderr: a bar (or, with no known total, a spinner)
    on a terminal, one line per stage otherwise (a log file, a CI job, a DNC server's
    console), nothing with --quiet."""

    def __init__(self, quiet: bool, total: int | None, first: str):
        self.console = Console(stderr=True, quiet=quiet)
        self.quiet = quiet
        self.total = total
        self.done = 0
        self.live = None
        if not quiet and self.console.is_terminal:
            if total:
                self.live = Progress(TextColumn("{task.description}"), BarColumn(),
                                     TimeElapsedColumn(), console=self.console, transient=True)
                self.task = self.live.add_task(first, total=total)
            else:
                self.live = self.console.status(first, spinner="dots")
        elif not quiet:
            click.echo(f"sdit-path: {first}", err=True)

    def __enter__(self):
        if self.live is not None:
            self.live.__enter__()
        return self

    def __exit__(self, *exc):
        if self.live is not None:
            self.live.__exit__(*exc)
        return False

    def note(self, message: str) -> None:
        """Say what is going on within a stage (the bar's text on a terminal; nothing in
        a log, which keeps one line per stage)."""
        if self.live is not None:
            if self.total:
                self.live.update(self.task, description=message)
            else:
                self.live.update(message)

    def __call__(self, message: str) -> None:
        self.done += 1
        if self.live is not None:
            if self.total:
                self.live.update(self.task, advance=1, description=message)
            else:
                self.live.update(message)
        elif not self.quiet:
            count = f"[{min(self.done, self.total)}/{self.total}] " if self.total else ""
            click.echo(f"sdit-path: {count}{message}", err=True)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="sdit-path")
def main() -> None:
    """Plan spatial double-ball-bar identification tests (SDIT) and write their NC
    programs (plan, preview); analyse the recordings of a test (analyse: geometry,
    effects and what stays unexplained; identify, diagnose); re-plan bad segments
    (replan); rehearse with simulated recordings (simulate, perturb)."""


@main.command("plan")
@click.argument("config", required=False, type=click.Path(dir_okay=False))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Output directory: DIR/<controller>/ programs and DIR/plan.json.")
@click.option("--force", is_flag=True,
              help="Replace DIR if it holds only an earlier output of this command.")
@click.option("--skip-infeasible", is_flag=True,
              help="Leave out segments that are unreachable or collide (plan.json says why).")
@click.option("--quiet", "-q", is_flag=True, help="No progress and no summary.")
def plan_command(config: str | None, out_dir: str, force: bool, skip_infeasible: bool,
                 quiet: bool) -> None:
    """Plan CONFIG (default: the bundled 3-axis sample) and write one program per layer
    and controller, plus plan.json."""
    from .output import check_output, write_tree
    from .plan.configure import load_config
    from .plan.manifest import plan_directory_files
    from .plan.pipeline import plan, step_count
    from .reports.plan import plan_table

    try:
        cfg = load_config(config)
        protect = (cfg.source,) if config else ()
        check_output(out_dir, force, "plan", protect)
        with _Steps(quiet, step_count(cfg), "planning") as step:
            result = plan(cfg, on_step=step, skip_infeasible=skip_infeasible)
            files = plan_directory_files(result, on_step=step)
            out = write_tree(out_dir, files, force=force, command="plan", protect=protect)
    except SditError as exc:
        _fail(exc)
        return
    if quiet:
        return
    out_console = Console()
    out_console.print(plan_table(result))
    masters = (f"; {result.masters[0].built.program.name} runs the layers in order with the "
               f"bar mounted once" if result.masters else "")
    out_console.print(f"wrote {len(files)} files to {out}/ (programs under "
                      f"{', '.join(c + '/' for c in cfg.post.controllers)}{masters}; manifest "
                      f"plan.json)")


@main.command("preview")
@click.argument("config", required=False, type=click.Path(dir_okay=False))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Output directory for the pictures (three PNGs per layer).")
@click.option("--feed", "feed", type=float, default=None,
              help="Preview at this feed (mm/min) instead of the config's.")
@click.option("--force", is_flag=True,
              help="Replace DIR if it holds only an earlier output of this command.")
@click.option("--skip-infeasible", is_flag=True, help="As for plan.")
@click.option("--plan", "plan_dir", type=click.Path(file_okay=False), default=None,
              help="Draw a plan as written (a directory of sdit-path plan) instead of "
                   "planning CONFIG again.")
@click.option("--quiet", "-q", is_flag=True, help="No progress.")
def preview_command(config: str | None, out_dir: str, feed: float | None, force: bool,
                    skip_infeasible: bool, plan_dir: str | None, quiet: bool) -> None:
    """Feed-profile pictures per layer: path speed over time, per-axis velocity,
    acceleration and jerk against their limits, and the hemisphere coloured by speed
    (by time where the speed holds the feed), with each layer's start and direction."""
    import dataclasses

    from .plan.configure import load_config
    from .errors import ConfigError
    from .output import check_output, write_tree
    from .plan.pipeline import plan, step_count
    from .plan.preview import preview
    from .reports.preview import preview_files

    try:
        if plan_dir is not None:
            from pathlib import Path

            from .plan.files import load_plan
            from .plan.preview import preview_of_plan

            for name, given in (("CONFIG", config), ("--feed", feed),
                                ("--skip-infeasible", skip_infeasible or None)):
                if given is not None:
                    raise ConfigError(name, "not with --plan: the plan as written is drawn "
                                            "(plan again to change it)")
            plan_files = load_plan(plan_dir)
            protect = (Path(plan_dir) / "plan.json",)
            check_output(out_dir, force, "preview", protect)
            with _Steps(quiet, len(plan_files.program_names), "reading the plan") as step:
                pv = preview_of_plan(plan_files)
                files = preview_files(pv, on_step=step)
                out = write_tree(out_dir, files, force=force, command="preview",
                                 protect=protect)
            if not quiet:
                Console().print(f"wrote {len(files)} pictures to {out}/ (timing: {pv.timing})")
            return
        cfg = load_config(config)
        protect = (cfg.source,) if config else ()
        check_output(out_dir, force, "preview", protect)
        if feed is not None:
            if not 1 <= feed <= 1e6:
                raise ConfigError("--feed", f"expected a feed in [1, 1e6] mm/min, got {feed:g}")
            cfg = dataclasses.replace(cfg, test=dataclasses.replace(cfg.test, feed_mm_per_min=feed))
        with _Steps(quiet, step_count(cfg) + len(cfg.test.track_elevations_deg),
                    "planning") as step:
            result = plan(cfg, on_step=step, skip_infeasible=skip_infeasible)
            files = preview_files(preview(result), on_step=step)
            out = write_tree(out_dir, files, force=force, command="preview", protect=protect)
    except SditError as exc:
        _fail(exc)
        return
    if not quiet:
        from .plan.preview import TIMING_TITLES

        Console().print(f"wrote {len(files)} pictures to {out}/ (timing: "
                        f"{TIMING_TITLES[cfg.timing.control]}, timing.control = "
                        f"\"{cfg.timing.control}\")")


def _controller_option(f):
    """``--controller``: whose programs were run (the expected reading follows the
    program as written for it: LinuxCNC's chords)."""
    return click.option(
        "--controller", default=None,
        help="The controller whose programs were run (sinumerik840d, linuxcnc, ...); the "
             "expected reading follows its program as written (LinuxCNC's chords). "
             "Default: the first the plan lists.")(f)


def _conditions_options(f):
    """What the user says of the test's conditions, shown in the report as given."""
    for name, helptext in (
            ("--date", "The test's date, as you want it in the report (the clock is never "
                       "read: equal input gives an equal report)."),
            ("--temperature", "A temperature, e.g. 'machine 21.4 C' (repeat)."),
            ("--instrument", "The ballbar's make and serial number."),
            ("--operator", "Who ran the test.")):
        f = click.option(name, name.lstrip("-") + "s" if name == "--temperature"
                         else name.lstrip("-"), multiple=name == "--temperature",
                         default=() if name == "--temperature" else None, help=helptext)(f)
    return f


def _conditions(operator, instrument, temperatures, date) -> list[tuple[str, str]]:
    """(what, value) for the report; one line of printable text each, at most 200
    characters (anything else is refused, naming the option)."""
    from .errors import ConfigError

    out = []
    for what, opt, values in (("operator", "--operator", [operator]),
                              ("instrument", "--instrument", [instrument]),
                              ("temperature", "--temperature", list(temperatures)),
                              ("date", "--date", [date])):
        for v in values:
            if v is None:
                continue
            if len(v) > 200 or not all(ch.isprintable() for ch in v):
                raise ConfigError(opt, "expected one line of printable text of at most 200 "
                                       "characters")
            out.append((what, v))
    return out


def _once_each(items: list[tuple[str, str | None]]) -> None:
    """Each recording file given once and each program named once, refused before any
    is read (found only after matching, a duplicate cost minutes of it)."""
    from pathlib import Path

    from .errors import ConfigError

    files: dict[Path, str] = {}
    named: dict[str, str] = {}
    for path, prog in items:
        key, given = Path(path).resolve(), path if prog is None else f"{prog}={path}"
        if key in files:
            raise ConfigError("--measured", f"{path}: given twice ({files[key]}, then {given}); "
                                            f"give each recording once")
        files[key] = given
        if prog is not None:
            if prog in named:
                raise ConfigError("--measured", f"{path}: a second recording of {prog} (the "
                                                f"first: {named[prog]}); give each program once")
            named[prog] = path


def _plan_sha256(plan_dir) -> str:
    import hashlib
    from pathlib import Path

    return hashlib.sha256((Path(plan_dir) / "plan.json").read_bytes()).hexdigest()


def _in_range(name: str, value: float, lo: float, hi: float) -> None:
    from .errors import ConfigError

    if not lo <= value <= hi:  # also refuses nan
        raise ConfigError(name, f"expected a value in [{lo:g}, {hi:g}], got {value:g}")


def _floats(text: str, n: int, name: str) -> tuple[float, ...]:
    from .errors import ConfigError

    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise ConfigError(name, f"expected {n} comma-separated numbers, got {text!r}") from None
    if len(values) != n:
        raise ConfigError(name, f"expected {n} comma-separated numbers, got {len(values)}")
    return values


@main.command("simulate")
@click.option("--plan", "plan_dir", required=True, type=click.Path(file_okay=False),
              help="A directory written by sdit-path plan.")
@click.option("--program", required=True, help="Program name, e.g. SDIT_A.")
@click.option("--errors", "errors_file", required=True,
              help="Error-set TOML, or a bundled one: paper_table2, five_axis_location.")
@click.option("--centring-um", default="0,0,0", show_default=True,
              help="Pivot ball centring offset x,y,z (um, table frame).")
@click.option("--bar-offset-um", default=0.0, show_default=True, help="Bar length offset (um).")
@click.option("--noise-um", default=0.0, show_default=True, help="Sensor noise, 1 sigma (um).")
@click.option("--quantisation-um", default=0.1, show_default=True, help="Instrument resolution (um).")
@click.option("--seed", default=0, show_default=True, help="Noise seed.")
@click.option("--out", "out_file", required=True, type=click.Path(dir_okay=False),
              help="Trace CSV to write.")
@click.option("--quiet", "-q", is_flag=True, help="No progress lines on stderr.")
@_controller_option
def simulate_command(plan_dir, program, errors_file, centring_um, bar_offset_um, noise_um,
                     quantisation_um, seed, out_file, quiet, controller) -> None:
    """Simulate the ballbar trace of PROGRAM for an error set."""
    from .errormodel.errorset import load_error_set
    from .output import write_file
    from .plan.files import load_plan
    from .reading.recording import trace_csv
    from .sim.simulate import simulate_trace

    try:
        _in_range("--noise-um", noise_um, 0, 1000)
        _in_range("--quantisation-um", quantisation_um, 0, 100)
        _in_range("--bar-offset-um", bar_offset_um, -1e4, 1e4)
        centring = _floats(centring_um, 3, "--centring-um")
        for v in centring:
            _in_range("--centring-um", v, -1e4, 1e4)
        with _Steps(quiet, 3, "reading the plan") as step:
            plan = load_plan(plan_dir).for_controller(controller)
            errors = load_error_set(errors_file)
            step(f"simulating {program}")
            trace = simulate_trace(plan, program, errors, centring, bar_offset_um, noise_um,
                                   quantisation_um, seed)
            step(f"writing {out_file}")
            write_file(out_file, trace_csv(trace))
            step("done")
    except SditError as exc:
        _fail(exc)
        return
    finite = np.isfinite(trace.delta_l_um)
    click.echo(f"wrote {out_file}: {int(finite.sum())} samples over {trace.t_s[-1]:.1f} s, "
               f"delta L {np.nanmin(trace.delta_l_um):.2f} .. {np.nanmax(trace.delta_l_um):.2f} um "
               f"({errors.name})")


@main.command("identify")
@click.option("--plan", "plan_dirs", multiple=True, required=True, type=click.Path(file_okay=False),
              help="Plan directory; repeat to pair with each --trace (one = all traces).")
@click.option("--trace", "traces", multiple=True, required=True, type=click.Path(dir_okay=False),
              help="Trace CSV; repeat to combine set-ups, feeds, directions.")
@click.option("--program", "programs", multiple=True,
              help="Program of each trace (default: the trace's '# program:' line).")
@click.option("--linear-order", default=0, show_default=True,
              help="Legendre degree of linear-axis errors (0 = constants).")
@click.option("--linear-basis", type=click.Choice(["legendre", "table"]), default="legendre",
              show_default=True)
@click.option("--rotary-order", default=0, show_default=True, help="Fourier harmonics of rotary errors.")
@click.option("--no-squareness", is_flag=True, help="Leave squareness out of the model.")
@click.option("--no-location", is_flag=True, help="Leave rotary location errors out.")
@click.option("--prior", is_flag=True,
              help="Also give every ISO parameter under a Tikhonov prior, labelled data- or prior-driven.")
@click.option("--ask", multiple=True, help="A parameter you need: say what would make it identifiable.")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), help="Write the full report.")
@click.option("--quiet", "-q", is_flag=True, help="No progress lines on stderr.")
@_controller_option
def identify_command(plan_dirs, traces, programs, linear_order, linear_basis, rotary_order,
                     no_squareness, no_location, prior, ask, json_out, quiet, controller) -> None:
    """Identify what the traces determine about the machine's geometric errors."""
    import json

    from .analyse.identification import identify_recordings
    from .errormodel.model import ModelOptions
    from .errors import ConfigError
    from .output import write_file
    from .plan.files import load_plan
    from .reports.identification import summary_text

    try:
        if len(plan_dirs) not in (1, len(traces)):
            raise ConfigError("--plan", f"give one plan, or one per trace ({len(traces)})")
        if programs and len(programs) != len(traces):
            raise ConfigError("--program", f"give one program per trace ({len(traces)})")
        with _Steps(quiet, 2 * len(traces) + 2, "reading the plan") as step:
            plans = [load_plan(d).for_controller(controller) for d in plan_dirs]
            options = ModelOptions(linear_basis, linear_order, rotary_order, not no_squareness,
                                   not no_location)
            result = identify_recordings(
                [(path, plans[k if len(plans) > 1 else 0], programs[k] if programs else None)
                 for k, path in enumerate(traces)], options, prior=prior, ask=tuple(ask),
                step=step)
            report = result.to_json()
            if json_out:
                write_file(json_out, json.dumps(report, indent=2) + "\n")
            step("done")
    except SditError as exc:
        _fail(exc)
        return
    click.echo(summary_text(report))


@main.command("analyse")
@click.option("--plan", "plan_dir", required=True, type=click.Path(file_okay=False),
              help="The directory written by sdit-path plan for the programs that were run.")
@click.option("--measured", "measured", required=True, multiple=True,
              help="A recording, FILE or PROGRAM=FILE (repeat, one per program run); without "
                   "PROGRAM= its program is recognised from its duration and dwells.")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Folder for analysis.json, analysis.txt, aligned/ and pictures/.")
@click.option("--force", is_flag=True, help="Replace an earlier analyse output in --out.")
@click.option("--linear-order", default=1, show_default=True,
              help="Legendre degree of linear-axis errors (0 = constants).")
@click.option("--rotary-order", default=0, show_default=True, help="Fourier harmonics of rotary errors.")
@click.option("--no-squareness", is_flag=True, help="Leave squareness out of the model.")
@click.option("--no-location", is_flag=True, help="Leave rotary location errors out.")
@click.option("--no-pictures", is_flag=True, help="Write no pictures.")
@click.option("--jobs", default=None, type=click.IntRange(1, 64),
              help="Worker processes for matching and diagnosis (default: one per core, as "
                   "many as --memory allows); the output is the same for any number.")
@click.option("--memory", "memory_mb", default=1024, show_default=True,
              type=click.IntRange(256, 1 << 20),
              help="MB the analysis may take, all its processes together: more lets it "
                   "diagnose recordings side by side (each takes about 2.8 MB per second "
                   "of its program).")
@click.option("--quiet", "-q", is_flag=True, help="No progress and no summary.")
@_controller_option
@_conditions_options
def analyse_command(plan_dir, measured, out_dir, force, linear_order, rotary_order,
                    no_squareness, no_location, no_pictures, jobs, memory_mb, quiet, controller,
                    operator, instrument, temperatures, date) -> None:
    """Analyse recordings of a plan's programs: geometry, effects and what stays
    unexplained, estimated together."""
    from pathlib import Path

    from .analyse import analyse
    from .errormodel.model import ModelOptions
    from .errors import ConfigError
    from .output import check_output, write_tree
    from .parallel import default_jobs
    from .plan.files import load_plan
    from .reading.recording import read_trace
    from .reports.analysis import analysis_files
    from .reports.diagnosis import pictures as diagnosis_pictures

    try:
        conditions = _conditions(operator, instrument, temperatures, date)
        plan = load_plan(plan_dir).for_controller(controller)
        items = []
        for m in measured:
            prog, sep, path = m.partition("=")
            if sep and prog in plan.program_names:
                items.append((path, prog))
            elif sep and prog and "/" not in prog and not Path(m).exists():
                raise ConfigError("--measured", f"{m[:80]}: {prog[:40]!r} is not a program of the "
                                                f"plan ({', '.join(plan.program_names)})")
            else:
                items.append((m, None))
        _once_each(items)
        protect = (Path(plan_dir) / "plan.json", *(p for p, _ in items))
        check_output(out_dir, force, "analyse", protect)
        n = len(items)
        with _Steps(quiet, 3 * n + 3, "reading the recordings") as step:
            recs = []
            for path, prog in items:
                step(f"reading {path}")
                recs.append((path, prog, read_trace(path)))
            options = ModelOptions("legendre", linear_order, rotary_order, not no_squareness,
                                   not no_location)
            result = analyse(plan, recs, options, step=step, note=step.note,
                             jobs=jobs or default_jobs(), memory_mb=memory_mb,
                             draw=None if no_pictures else diagnosis_pictures)
            step("writing the report")
            files = analysis_files(result, plan, _plan_sha256(plan_dir), conditions)
            write_tree(out_dir, files, force=force, command="analyse", protect=protect)
    except SditError as exc:
        _fail(exc)
        return
    if not quiet:
        click.echo(files["analysis.txt"], nl=False)


@main.command("report")
@click.option("--plan", "plan_dir", required=True, type=click.Path(file_okay=False),
              help="A directory written by sdit-path plan.")
@click.option("--analysis", "analysis_file", type=click.Path(dir_okay=False),
              help="analysis.json written by sdit-path analyse of recordings of this plan "
                   "(its aligned/ folder beside it); without, the plan's report.")
@click.option("--out", "out_file", required=True, type=click.Path(dir_okay=False),
              help="The HTML file to write (one self-contained file; prints to A4).")
@click.option("--force", is_flag=True, help="Replace an earlier report at --out.")
@click.option("--quiet", "-q", is_flag=True, help="No progress lines on stderr.")
@_controller_option
@_conditions_options
def report_command(plan_dir, analysis_file, out_file, force, quiet, controller, operator,
                   instrument, temperatures, date) -> None:
    """Write the test report: one HTML file with the plan and, with --analysis, the
    results in the trade's terms."""
    from pathlib import Path

    from .analyse.sphere import deviations
    from .analyse.stored import load_analysis
    from .errors import OutputError
    from .output import write_file
    from .plan.files import load_plan
    from .reports.html import GENERATOR, report_html

    try:
        conditions = _conditions(operator, instrument, temperatures, date)
        target = Path(out_file)
        inputs = [Path(plan_dir) / "plan.json", *([Path(analysis_file)] if analysis_file else [])]
        if any(target.resolve() == p.resolve() for p in inputs):
            raise OutputError(f"{out_file}: is an input of this report; choose another --out")
        if target.is_dir():
            raise OutputError(f"{out_file}: is a directory; expected a file name")
        if target.exists():
            if not force:
                raise OutputError(f"{out_file}: exists; --force replaces an earlier report")
            head = target.read_bytes()[:4096].decode("utf-8", "replace")
            if f'content="{GENERATOR}"' not in head:
                raise OutputError(f"{out_file}: is not a report written by sdit-path; not "
                                  f"replaced")
        with _Steps(quiet, 3, "reading the plan") as step:
            sha = _plan_sha256(plan_dir)
            plan = load_plan(plan_dir)
            data, traces = None, []
            if analysis_file:
                step(f"reading {analysis_file}")
                data, traces = load_analysis(analysis_file, plan, sha)
                said = (data.get("plan") or {}).get("controller")
                controller = controller or said
            plan = plan.for_controller(controller)
            step("drawing the report")
            try:
                text = report_html(plan, sha, data, deviations(plan, traces), conditions)
            except (KeyError, TypeError, ValueError, IndexError) as exc:
                from .errors import ConfigError

                raise ConfigError(analysis_file or plan_dir,
                                  f"a field the report reads is missing or of the wrong kind "
                                  f"({type(exc).__name__}: {str(exc)[:80]}); not an output of "
                                  f"this version of sdit-path") from None
            write_file(out_file, text)
    except SditError as exc:
        _fail(exc)
        return
    except OSError as exc:
        from .errors import OutputError as _OE

        _fail(_OE(f"{out_file}: {exc.strerror or exc}"))
        return
    if not quiet:
        click.echo(f"wrote {out_file}")


@main.command("replan")
@click.option("--plan", "plan_dir", required=True, type=click.Path(file_okay=False),
              help="A directory written by sdit-path plan.")
@click.option("--segment", "segments", multiple=True,
              help="Re-plan this segment's sector (repeat), e.g. D3-2; default: every bad one.")
@click.option("--analysis", "analysis_file", type=click.Path(dir_okay=False),
              help="analysis.json of recordings of this plan: segments it left unexplained "
                   "count as bad too.")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Folder for the re-planned plan, replan.json and replan.txt.")
@click.option("--force", is_flag=True, help="Replace an earlier replan output in --out.")
@click.option("--jobs", default=None, type=click.IntRange(1, 64),
              help="Worker processes for the candidate curves (default: one per core); "
                   "the output is the same for any number.")
@click.option("--quiet", "-q", is_flag=True, help="No progress and no summary.")
def replan_command(plan_dir, segments, analysis_file, out_dir, force, jobs, quiet) -> None:
    """Find a plan's bad segments, say why, re-plan their sectors and write the
    re-planned plan (the config carries the new curves as overrides)."""
    from pathlib import Path

    from .output import check_output, write_tree
    from .parallel import default_jobs
    from .plan.files import load_plan
    from .replan import replan
    from .replan.run import analysis_file_reasons, replanned_plan
    from .reports.replan import replan_files, report_text

    try:
        old = load_plan(plan_dir)
        measured = analysis_file_reasons(old, analysis_file) if analysis_file else None
        protect = (Path(plan_dir) / "plan.json", Path(plan_dir) / "config.toml",
                   *((analysis_file,) if analysis_file else ()))
        check_output(out_dir, force, "replan", protect)
        with _Steps(quiet, None, "reviewing the plan") as step:
            result = replan(old, list(segments) or None, on_step=step.note, measured=measured,
                            on_stage=step, jobs=jobs or default_jobs())
            if not result.changed:
                text = report_text(result) + (
                    f"Nothing changed: every sector keeps its curve, so no plan is written "
                    f"({out_dir} is left as it was).\n")
                if not quiet:
                    click.echo(text, nl=False)
                return
            step("planning with the chosen curves")
            planned = replanned_plan(old, result, on_step=step.note)
            files = replan_files(result, planned, str(Path(plan_dir).name), on_step=step.note)
            step("writing")
            write_tree(out_dir, files, force=force, command="replan", protect=protect)
    except SditError as exc:
        _fail(exc)
        return
    if not quiet:
        click.echo(files["replan.txt"], nl=False)


@main.command("perturb")
@click.option("--plan", "plan_dir", required=True, type=click.Path(file_okay=False),
              help="A directory written by sdit-path plan.")
@click.option("--program", required=True, help="Program name, e.g. SDIT_C.")
@click.option("--model", "model_file", default=None,
              help="Geometric error set of the machine (TOML or bundled name); default none.")
@click.option("--effect", "effects", multiple=True,
              help="Hidden effect 'name:key=value,...' (repeat); e.g. servo_lag:kv_per_s=30.")
@click.option("--seed", default=None, type=int,
              help="Draw the hidden effects and the recording from this seed instead.")
@click.option("--noise-um", default=None, type=float, help="Sensor noise (um, 1 sigma).")
@click.option("--lead-s", default=None, type=float, help="Recording starts this early (s).")
@click.option("--clock-ppm", default=None, type=float, help="Instrument clock error (ppm).")
@click.option("--out", "out_file", required=True, type=click.Path(dir_okay=False),
              help="Measured-trace CSV to write (t_s, delta_l_um).")
@click.option("--truth", "truth_file", type=click.Path(dir_okay=False),
              help="Write what was hidden here (never into the trace).")
@click.option("--control", default=None, type=click.Choice(["linuxcnc"]),
              help="Make the recording from the motion of a real control running the "
                   "program as written for it (LinuxCNC 2.9's planner: its chords, ramps, "
                   "blends and slow-downs; its dwells 2-30 ms longer than programmed, by its "
                   "wall clock) instead of the plan's trajectory.")
@click.option("--dwell-extra-ms", default="2,30", show_default=True,
              help="With --control: each dwell lasts longer than programmed by a seeded "
                   "amount in LO,HI ms (a control's wall clock); 0,0 for exact dwells.")
@click.option("--quiet", "-q", is_flag=True, help="No progress lines on stderr.")
def perturb_command(plan_dir, program, model_file, effects, seed, noise_um, lead_s, clock_ppm,
                    out_file, truth_file, control, dwell_extra_ms, quiet) -> None:
    """Make a realistic measured trace of PROGRAM with hidden effects."""
    import json
    from pathlib import Path

    from .reading.context import build_context
    from .errormodel.errorset import load_error_set
    from .errors import ConfigError, OutputError
    from .output import write_file
    from .plan.files import load_plan
    from .reading.recording import measured_csv
    from .sim.perturb import hidden_and_recording, perturb, truth_json

    try:
        for name, v, lo, hi in (("--noise-um", noise_um, 0, 100), ("--lead-s", lead_s, 0, 600),
                                ("--clock-ppm", clock_ppm, -1000, 1000)):
            if v is not None:
                _in_range(name, v, lo, hi)
        with _Steps(quiet, 3, "reading the plan") as step:
            plan = load_plan(plan_dir)
            model = load_error_set(model_file) if model_file else None
            control_runs = None
            dwell_extra = None
            if control:
                from .plan.control_motion import control_plan, longer_dwells

                plan, control_runs = control_plan(plan, program, control)
                try:
                    lo, hi = (float(v) for v in dwell_extra_ms.split(","))
                except ValueError:
                    raise ConfigError("--dwell-extra-ms", f"{dwell_extra_ms[:40]!r}: expected "
                                                          f"LO,HI in ms, e.g. 2,30") from None
                _in_range("--dwell-extra-ms", lo, 0, 1000)
                _in_range("--dwell-extra-ms", hi, lo, 1000)
                if hi > 0:
                    plan, dwell_extra = longer_dwells(plan, program, control, seed or 0,
                                                      (lo * 1e-3, hi * 1e-3))
            ctx = build_context(plan, program)
            hidden, rec = hidden_and_recording(ctx, effects, seed, noise_um=noise_um,
                                               lead_s=lead_s, clock_ppm=clock_ppm)
            for target in (out_file, truth_file):
                if target and Path(target).is_dir():
                    raise OutputError(f"{target}: is a directory")
            step(f"simulating {program} with {len(hidden)} hidden effect(s)")
            trace, truth = perturb(plan, program, model, hidden, rec, seed or 0, ctx)
            step(f"writing {out_file}")
            write_file(out_file, measured_csv(trace))
            if truth_file:
                told = truth_json(truth)
                if control_runs is not None:
                    told["control"] = {"name": control, "runs": control_runs,
                                       "dwell_extra_ms": dwell_extra}
                write_file(truth_file, json.dumps(told, indent=2) + "\n")
    except SditError as exc:
        _fail(exc)
        return
    click.echo(f"wrote {out_file}: {len(trace.t_s)} samples over {trace.t_s[-1]:.1f} s "
               f"({len(hidden)} hidden effect(s){'; truth in ' + truth_file if truth_file else ''})")


@main.command("diagnose")
@click.option("--plan", "plan_dir", required=True, type=click.Path(file_okay=False),
              help="A directory written by sdit-path plan.")
@click.option("--program", required=True, help="Program the trace recorded, e.g. SDIT_C.")
@click.option("--measured", "measured", required=True, type=click.Path(dir_okay=False),
              help="Measured trace CSV (t_s and delta_l_um or delta_l_mm).")
@click.option("--model", "model_file", default=None,
              help="Geometric error set to simulate with (TOML or bundled name); default none.")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), help="Write the report as JSON.")
@click.option("--pictures", "pic_dir", type=click.Path(file_okay=False),
              help="Write residual_time.png and residual_hemisphere.png here.")
@click.option("--quiet", "-q", is_flag=True, help="No summary on stdout.")
@_controller_option
def diagnose_command(plan_dir, program, measured, model_file, json_out, pic_dir, quiet,
                     controller) -> None:
    """Diagnose the gap between the simulated and the measured trace of PROGRAM."""
    import json
    from pathlib import Path

    from .analyse.diagnosis import diagnose_recording
    from .errormodel.errorset import load_error_set
    from .errors import ConfigError
    from .output import write_file
    from .plan.files import load_plan
    from .reading.recording import read_trace
    from .reports.diagnosis import pictures, summary_text

    try:
        plan = load_plan(plan_dir).for_controller(controller)
        if program not in plan.program_names:
            raise ConfigError(plan_dir, f"no program {program!r}; programs: "
                                        f"{', '.join(plan.program_names)}")
        model = load_error_set(model_file) if model_file else None
        trace = read_trace(measured)
        with _Steps(quiet, None, "diagnosing") as step:
            result, ctx = diagnose_recording(plan, program, trace, str(measured), model, step)
        report = result.to_json()
        if json_out:
            write_file(json_out, json.dumps(report, indent=2) + "\n")
        if pic_dir:
            for name, png in pictures(result, ctx).items():
                write_file(Path(pic_dir) / f"{name}.png", png)
    except SditError as exc:
        _fail(exc)
        return
    if not quiet:
        click.echo(summary_text(result), nl=False)
