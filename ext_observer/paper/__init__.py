"""The paper's commands: ``python -m ext_observer reproduce`` (``reproduce``)."""
