"""The built-in tasks, each a :class:`~adworker.tasks.base.Task` that a
:class:`~adworker.tasks.base.RobotEnv` composes with the simulator and the robot. They
are declared (name, options model, factory) in ``adclient.builtin_tasks``."""
