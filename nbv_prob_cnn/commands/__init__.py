"""Sub-commands of the ``nbv`` command line, one module each."""
