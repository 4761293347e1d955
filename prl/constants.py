"""Names shared by the hand model, the simulator side and the label maths.

The order of these tuples is the order of every joint / sensor vector in the
project (trajectories, datasets, templates, grasp patterns).
"""

from __future__ import annotations

from pathlib import Path

#: The checkout's root directory (assets, the MLflow store and outputs live under it).
REPO_ROOT = Path(__file__).resolve().parents[1]

#: The 30 joints of the hand-arm, in vector order: 3 prismatic arm joints along
#: world X, Y, Z; 3 revolute arm joints about local X, Y, Z; 2 wrist joints; 22
#: finger joints in the Shadow Hand layout.
JOINT_NAMES: tuple[str, ...] = (
    "ARTx", "ARTy", "ARTz", "ARRx", "ARRy", "ARRz",
    "WRJ2", "WRJ1",
    "FFJ4", "FFJ3", "FFJ2", "FFJ1",
    "MFJ4", "MFJ3", "MFJ2", "MFJ1",
    "RFJ4", "RFJ3", "RFJ2", "RFJ1",
    "LFJ5", "LFJ4", "LFJ3", "LFJ2", "LFJ1",
    "THJ5", "THJ4", "THJ3", "THJ2", "THJ1",
)
N_JOINTS = len(JOINT_NAMES)

#: The 17 contact-sensor patches, in vector order (palm and phalanges).
SENSOR_NAMES: tuple[str, ...] = (
    "palm",
    "ff_proximal", "ff_middle", "ff_distal",
    "mf_proximal", "mf_middle", "mf_distal",
    "rf_proximal", "rf_middle", "rf_distal",
    "lf_metacarpal", "lf_proximal", "lf_middle", "lf_distal",
    "th_proximal", "th_middle", "th_distal",
)
N_SENSORS = len(SENSOR_NAMES)

#: Number of anchor points on the palm (paper Fig 3).
N_ANCHORS = 6

#: Size of the Representation Space per dimension, from the rows of paper Table II:
#: a4 (kinematic motion) lists 7 choices and a5 (tool-object rotation) 6. The paper's
#: text writes "[7, 7, 6, 4, 6, 7]", which contradicts its own table; we follow the
#: table (same 49,392 plans). ``assets/plb.yaml`` is the source of truth; a test
#: checks this tuple against it.
RS_DIMS: tuple[int, ...] = (7, 7, 6, 4, 7, 6)

TASKS: tuple[str, ...] = ("hammer", "sweep", "unscrew", "tweeze")

#: Physics steps per second of every task scene (PhysX, CPU). 250 Hz with 20 solver position iterations
#: (``envs/tasks/base.py``) was chosen by the fidelity study of ``bench/bench_physics.py`` (docs/guide/physics.md): it
#: agrees with a converged reference as often as the former 500 Hz / 25 did, at about half the cost.
SIM_FREQ = 250
#: Simulated duration of one plan episode, s. The paper's "1500 frames" is an Isaac Sim count with an
#: unstated step; this project ran them at 500 Hz (3 s) until 2026-12-01 and keeps the 3 s.
EPISODE_SECONDS = 3.0
#: Physics frames of one plan episode at ``SIM_FREQ`` (750).
EPISODE_FRAMES = int(round(SIM_FREQ * EPISODE_SECONDS))
#: Recorded frames per second of a demonstration (the LeRobot dataset's fps): every 5th physics frame.
RECORD_HZ = 50
