"""``python -m online_em_slam.messages.tf2_build``: the ``online-em-slam-tf2-msgs`` command."""
import sys

from .cli import main

sys.exit(main())
