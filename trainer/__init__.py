"""trainer: PPO grasping policies on batched MuJoCo, consuming geomprep's processed assets.

``config`` holds every knob as frozen dataclasses (loaded from TOML); ``env`` is the batched
UR5e + Schunk SIH lifting task (the model from ``assets``, simulated by ``sim``, observed through
``kinematics``, ``objects`` and ``representations``, reset from ``init_states``); ``models`` and
``ppo`` are the policy and its training; ``evaluation``, ``video`` and ``report`` judge a trained
run; ``scripted`` is a scripted grasp that shows the physics can grasp; ``cli`` is the
``trainer`` command. The data it reads is described in README.md ("The data contract").
"""
