from description import thesis


def test_datasets_hold_the_thesis_mug_counts() -> None:
    counts = {n: (d.big, d.small) for n, d in thesis.DATASETS.items()}
    assert counts == {1: (6, 6), 2: (8, 4), 3: (4, 8), 4: (20, 10), 5: (15, 15), 6: (10, 20)}


def test_robot_tray_datasets_use_the_robot_tray() -> None:
    trays = [d.tray_mm for d in thesis.DATASETS.values()]
    assert trays == [thesis.ROBOT_TRAY_MM] * 3 + [thesis.FULL_TRAY_MM] * 3


def test_servo_per_joint_follows_the_chain_order() -> None:
    assert [j for j, _ in thesis.JOINT_SERVOS] == [r.joint for r in thesis.DH_TABLE]
