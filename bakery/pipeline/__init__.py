"""The bake pipeline: plan → execute (local processes or Dask) → single writer.

The parent reads the inputs and the recipe and emits picklable :class:`~bakery.pipeline.plan.BatchTask` s; workers
capture and encode (:func:`~bakery.pipeline.worker.run_batch`); the parent alone merges results and writes the
store (and, for scenes, the USD layer), checkpointing finished batches so that a killed bake resumes.
"""
