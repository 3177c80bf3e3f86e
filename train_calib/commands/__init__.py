"""Subcommands of ``train-calib``, one module each (see ``train_calib.cli``)."""
