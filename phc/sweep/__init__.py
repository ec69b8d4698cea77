"""`phc sweep`: parameter studies — grids, Latin-hypercube and random samples — on a local
process pool or a Dask cluster.

Input: a model or scene file and the swept values (``NAME=SPEC``, :mod:`phc.spec.sweep`,
and a scene's ``sweep:`` section). Output: one row per run in a CSV file (and Parquet
with pyarrow), optionally the time series of every run in a second CSV file.

How a sweep runs
----------------
* **One compilation per sweep.** The model is compiled once in this process; parameters
  are run-time arguments of the generated module. Compile-time parameters (a mesh length,
  a coefficient varying along a distributed component) and ``accuracy.mesh.COMPONENT``
  group the points by compilation: each group is compiled once
  (:func:`phc.frontend.scene.scene_variant`, nothing written).
* **Workers get the compiled model by value**: a :class:`~phc.pipeline.CompiledModel`
  pickles as its generated source plus metadata and is rebuilt on the worker from the
  text in memory (:func:`phc.codegen.load.load_generated`); workers never read a model
  file (each point's parameter values are checked against the model file here, before it
  is sent: :func:`phc.simulation.check_parameters`, whose verdict travels with the point).
  A pickle is code to whoever loads it, so it travels only from this process to the
  workers it starts or the Dask cluster the user names (see docs/security.md).
* **Executors**: a local process pool (default; one BLAS thread per worker) or Dask
  distributed (``pip install "port-hamiltonian-compiler[cluster]"``): a ``LocalCluster`` or a running scheduler.
  The same function runs every point in both.
* **Robustness**: a point that fails (the solver stops, the start is inconsistent, a
  parameter makes the model impossible to evaluate) is a row with ``success`` false and
  its message. Rows are appended to the CSV file as they arrive, each by one ``write`` of
  one complete line to a file opened for appending, then flushed to disk; ``resume``
  skips the points already there (a torn last line is dropped; ``retry_failed`` runs the
  failed ones again) and accepts only results of the same model, values and phc version.
  A point whose worker died while running it is run again elsewhere (the local pool
  replaces that process alone; Dask reschedules it) and the row's ``attempts`` says so; a
  point is charged only for its own runs. When the sweep completes the CSV file is
  rewritten in point order.
* **The design is streamed**: points are made on demand (:class:`~phc.sweep.design.Points`),
  checked a point ahead of the workers and sent as they free up, and rows are kept as typed columns
  (:class:`~phc.sweep.results.RowTable`): a 10⁶-point sweep starts at once in bounded memory.
* **Swept names are columns**: a name that is also a result column (``steps``,
  ``worker``, ``x.max`` of an output ``x``) is refused where it is written.

The package, in the order a sweep runs:

* :mod:`phc.sweep.design` — swept names, points, compilation groups;
* :mod:`phc.sweep.run` — :func:`run_sweep`: compile, open the results files, run, record;
* :mod:`phc.sweep.executors` — one point, the local process pool, Dask;
* :mod:`phc.sweep.results` — the columns of a row, the CSV append log, the report, Parquet;
* :mod:`phc.sweep.plot` — the plot of the results.

Every public name of these modules is importable from ``phc.sweep`` too.
"""

# every public name phc.sweep had as one module; __all__ is what it was
from phc.errors import SweepSetupError  # noqa: F401
from phc.sweep.design import (ACCURACY_OPTIONS, MAX_POINTS, MESH_PREFIX, Design, Point, Points, compile_group,
                              group_label, make_design, recompile_for, sample_unit, sweep_axes, transform)  # noqa: F401
from phc.sweep.executors import (INSTALL_CLUSTER, MAX_ATTEMPTS, DaskExecutor, LocalExecutor, default_workers,
                                 run_point, start_method)  # noqa: F401
from phc.sweep.plot import INSTALL_PLOT, plot_sweep  # noqa: F401
from phc.sweep.results import (INSTALL_PARQUET, MACHINE_COLUMNS, RUN_COLUMNS, STATS, AppendLog, RowTable, SweepReport,
                               parquet_available, read_results, results_paths, write_parquet)  # noqa: F401
from phc.sweep.run import run_sweep  # noqa: F401

__all__ = ["AppendLog", "DaskExecutor", "Design", "LocalExecutor", "Point", "SweepReport", "SweepSetupError",
           "make_design", "plot_sweep", "read_results", "recompile_for", "results_paths", "run_point", "run_sweep",
           "sample_unit"]
