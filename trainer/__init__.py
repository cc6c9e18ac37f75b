"""trainer: PPO grasping policies on batched MuJoCo, consuming geomprep's processed assets.

``config`` holds every knob as frozen dataclasses (loaded from TOML); ``tasks`` are the batched
UR5e + Schunk SIH grasping tasks (``lift``, ``bin``; ``tasks.make_env`` builds one) on scenes with
object slots (the model from ``assets``, simulated by a ``sim`` backend, observed through
``kinematics``, ``objects`` and ``representations``, reset from ``init_states``); ``models`` and
``ppo`` are the policy and its training loop (the run's state, run directory and checkpoints in
``training``); ``evaluation``, ``video`` and ``report`` judge a trained run; ``grasps`` are
scripted grasp families (top, pinch) that show what the physics can grasp, each trial's outcome
classified; ``robots`` the robots (UR5e + SIH hand, floating hand) as parts; ``randomness`` the
run's one seed and its streams; ``cli`` is the ``trainer`` command. The data it reads is
described in docs/data-contract.md; the parts in docs/architecture.md.
"""
