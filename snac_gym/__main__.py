"""``python -m snac_gym``: the ``snac-gym`` command, where the environment's scripts folder is not on ``PATH``."""

from snac_gym.apps.cli import main

if __name__ == "__main__":
    main()
