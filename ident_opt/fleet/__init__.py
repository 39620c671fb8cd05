"""`ident-opt fleet`: every robot of a fleet identified every day, and what changed, on Dask.

Sufficient statistics make identification a map-reduce: a trial becomes YᵀY, Yᵀτ, τᵀτ and n (`fitting.stats`),
and those add up. The modules, in the order a run uses them:

| module      | what it holds                                                                                   |
|-------------|-------------------------------------------------------------------------------------------------|
| `layout`    | the fleet layout ROOT/robot=<id>/day=<YYYY-MM-DD>/<file> found and checked (`data-format.md`)   |
| `store`     | what each file gave, kept between runs in one SQLite file (`--store`), under a model key        |
| `incremental`| phase 1 with the store: only new or changed files go to the cluster; the rest from the store  |
| `tasks`     | what runs on a worker: a file's statistics (the loader every command uses), a day's fit, a      |
|             | robot's baseline model and each day's evidence for the named causes; samples never leave it     |
| `streamed`  | a long log's statistics read in pieces (memory flat in its length), with `chunks`: the          |
|             | zero-phase filters and derivatives of a piece with the overlap its filter's poles ask for       |
| `engine`    | the Dask client (a local cluster, or an existing scheduler) and the task graph with its progress |
| `interrupts`| Ctrl-C and SIGTERM during a run: the workers ignore them, the client takes them between Dask's   |
|             | calls, closes the cluster and kills what is left                                                |
| `changes`   | per robot: the baseline, the test that separates a change from day-to-day scatter, its cause    |
| `alerts`    | changes.jsonl and metrics.prom (Prometheus' text format) beside the reports                    |
| `simulated` | a simulated fleet with hidden changes, for tests and the benchmark (`python -m ...simulated`)   |

`ident_opt.fleet.run` runs them in that order; `ident_opt.report.fleet` writes what they found.
"""
