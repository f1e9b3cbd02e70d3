"""What the robot and its cell are, as data: the bottom layer every other package may import.

``thesis`` holds the reference thesis's figures with the table or section each comes from (mug catalogue,
trays, datasets, DH table, servos, camera pose); ``arm`` the arm description (URDF, joint limits, gripper
geometry) with ``servos`` the Dynamixel models; ``camera`` and ``cell`` the one cell-layout type (counter,
flip area, tray, camera). Nothing here imports another dishbot package, does I/O or needs a heavy library.
"""
