"""trainer: PPO grasping policies on batched MuJoCo, consuming geomprep's processed assets.

Not built yet: the environment, the robot and the PPO loop are the subject of later issues.
The data it will read is described in README.md ("The data contract").
"""
