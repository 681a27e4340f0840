"""python -m rvd_pil.qemu.plugin: fetch the matching qemu-plugin.h and build the plugin."""
import sys

from . import main

sys.exit(main())
