"""The paper's robot experiment (Section V-C, Table III) in simulation.

Given a task, a policy picks one grasp rectangle on a noisy depth image of a
fresh pile of 3-6 tools; the rectangle is lifted to a top-down 6-DoF grasp
and executed with the one simulated gripper among the whole pile (approach,
close, lift, hold); the trial succeeds for GSR-S when a tool whose category
can do the task is lifted and held, and for GSR-T when it is also held the
way the task needs. ``togcrf robot-eval`` runs the protocol
(``docs/togcrf-robot.md``).

Modules: :mod:`~togcrf.robot.protocol` (trials, piles' seeds),
:mod:`~togcrf.robot.world` (the pipeline's tools, grasps and stages'
parameters), :mod:`~togcrf.robot.observation` (what the robot sees of a pile),
:mod:`~togcrf.robot.pile` (piles, their depth images, feasible piles),
:mod:`~togcrf.robot.policies` (oracle, random, checkpoints),
:mod:`~togcrf.robot.lifting` (rectangle to top-down grasp),
:mod:`~togcrf.robot.execute` (simulation, judgement),
:mod:`~togcrf.robot.report` (trial log, Table III),
:mod:`~togcrf.robot.pictures` (failure pictures), :mod:`~togcrf.robot.run`
(the loop), :mod:`~togcrf.robot.cli` (the commands).

Unlike the rest of ``togcrf``, which reads the generator's data through
:mod:`osgd.contract` only, this runs the generator's physics and rendering
(pybullet, trimesh, embreex), through :mod:`osgd.simulation` only; the
commands of :mod:`~togcrf.robot.cli` import it when they run.
"""
