"""A training run's state, each part in one place (the loop itself: ``trainer.ppo.train``).

- ``run_dir``: ``RunDir``, the run on disk: config.json, metrics.csv, tb/, checkpoints/.
- ``checkpoint``: ``TrainState`` (everything carried from one iteration to the next, with
  ``state_dict`` / ``load_state_dict``), reading and writing checkpoint files, ``load_agent``.
- ``curriculum``: ``LiftCurriculum``, the training lift target that rises with success.
- ``outcomes``: ``EpisodeStats`` and ``ObjectOutcomes``, what the ended episodes say.
- ``progress``: the per-iteration metrics row, TensorBoard scalars and progress bar.
- ``stop``: SIGINT / SIGTERM end a run at the end of its iteration, with a checkpoint.

Nothing is imported here, so that ``run_dir`` stays importable without torch.
"""
