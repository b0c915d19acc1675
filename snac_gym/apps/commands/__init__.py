"""The ``snac-gym`` subcommands, one module per group: :mod:`~snac_gym.apps.commands.simulation` (``demo``,
``bench``, ``plot``), :mod:`~snac_gym.apps.commands.real` (``real``, ``emulate-ur``),
:mod:`~snac_gym.apps.commands.evaluate` and :mod:`~snac_gym.apps.commands.train` (``train-ppo``);
:mod:`snac_gym.apps.cli` assembles them into one typer app.
"""
