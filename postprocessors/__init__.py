"""Built-in post-processors, one module per controller.

Each module provides a class with ``name``, ``title``, ``extension``, ``path_form``,
``render(program) -> str`` (pure: no file IO, no clock, no mutation) and
``lint(text, travel_mm) -> list[str]``.  They are registered explicitly in
:mod:`sdit_path.nc.registry`; third parties register theirs under the entry-point
group ``sdit_path.postprocessors``.
"""
