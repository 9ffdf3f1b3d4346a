"""The subcommands of ``fisheye-infer``, one module each: ``configure(parser)`` adds its flags and
sets ``run``, ``run(args) -> exit code`` does the work. ``fisheye_infer.cli`` is the table of them.

Each module imports only argparse-level things at import time; the runtime, torch, the web stack,
Ray and Triton are imported when the command runs, so ``fisheye-infer --help`` works on the core
install and a missing extra is named with its install line (``common.missing_extra``).
"""
