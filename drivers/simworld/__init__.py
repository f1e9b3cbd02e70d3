"""The simulated cell on MuJoCo: the static scene (``scene``), the depth camera (``camera``) and the physical
world with the arm, gripper and force sensing built on them."""
