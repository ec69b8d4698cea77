"""The `phc` command line: validate, check, graph, compile, simulate, sweep, export, schema.

Exit codes: 0 success, 1 model errors (or a failed simulation), 2 usage errors.
A user mistake never produces a traceback: it is printed as one located line per
problem. Set ``PHC_DEBUG=1`` to see tracebacks of internal errors.

This package holds :func:`main` (a command run with its exit code); the rest is split by
what it does, and every name is importable from ``phc.cli`` too:

* :mod:`phc.cli.parser` — the argument parser, the limits of the numeric options and the
  accepted output paths (checked before any work), the wrappers of every command;
* :mod:`phc.cli.commands` — one ``cmd_NAME`` per subcommand;
* :mod:`phc.cli.run` — setting up and guarding a run (compile or exit, progress, initial
  values, settings the solver ignores);
* :mod:`phc.cli.report` — exit codes, diagnostics, summary lines, result files and plots.
* :mod:`phc.cli.report_formats` — GitHub Actions annotations and SARIF 2.1.0 for CI.
"""

from __future__ import annotations

import os
import sys
import warnings
from typing import Optional, Sequence

from phc import PhcError
from phc.inert import printable
from phc.cli.commands import (  # noqa: F401 (importable from phc.cli)
    MAX_FILE_STEM, _draw_png, _parse_assignments, _parse_params, cmd_animate, cmd_bench, cmd_cache, cmd_check,
    cmd_compile, cmd_export, cmd_graph, cmd_linearize, cmd_schema, cmd_simulate, cmd_sweep, cmd_validate)
from phc.cli.parser import (  # noqa: F401 (importable from phc.cli)
    FORMAT_HELP, NUMERIC_OPTIONS, OUTPUT_OPTIONS, _allowed_paths, _check_arguments, _check_number, _memory_size,
    _python_showwarning, _show_warning, _solver_names, _with_budget, build_parser)
from phc.cli.report import (  # noqa: F401 (importable from phc.cli)
    EXIT_INTERRUPTED, EXIT_MODEL, EXIT_OK, EXIT_USAGE, _backend_line, _certificate_line, _compiled_json, _csv_header,
    _event_text, _Exit, _Files, _left_out_lines, _part_line, _plot, _print_diagnostics, _size_text, _summary_text,
    _write_results)
from phc.cli.run import (  # noqa: F401 (importable from phc.cli)
    _ACCURACY_KEYS, _INCONSISTENT_HINT, _compile_or_exit, _ignored_in_file_lines, _inconsistent_lines,
    _initial_spans, _initial_spans_from_files, _progress_for, _recompile_for_params, _simulation_errors,
    _written_options)
from phc.errors import UsageError  # noqa: F401 (its old home, phc.errors says)


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    warnings.showwarning = _show_warning
    try:
        _check_arguments(args)
        with _allowed_paths(args):
            return args.func(args)
    except _Exit as done:
        return done.code
    except UsageError as err:
        print(f"phc {args.command}: error: {printable(str(err), quoted=False)}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("phc: interrupted", file=sys.stderr)
        return 130
    except PhcError as err:  # phc's own exceptions are about the input or the run, not internal
        print(f"phc {args.command}: error: {printable(str(err), quoted=False)}", file=sys.stderr)
        return EXIT_MODEL
    except BrokenPipeError:  # the reader went away (`phc ... | head`): not an error of ours
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK
    except Exception as err:  # an internal error, not a user mistake
        if os.environ.get("PHC_DEBUG"):
            raise
        print(f"phc {args.command}: internal error: {type(err).__name__}: {printable(str(err), quoted=False)} "
              "(please report it; rerun with PHC_DEBUG=1 for a traceback)", file=sys.stderr)
        return EXIT_USAGE
