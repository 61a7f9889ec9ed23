"""Many bags, and long bags cut into time windows, processed as tasks on local worker processes or Ray.

`run.process_many` is the entry point; each task calls `stereo_depth.bag.process.process_bag`, so a
bag processed here equals the same bag processed alone. Layout: inputs (which bags, which outputs),
tasks (what a worker runs), shards (windows of a long bag and their merge), backends (local pool, Ray),
report (progress line, failures, JSON report).
"""
