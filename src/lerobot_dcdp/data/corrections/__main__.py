"""``python -m lerobot_dcdp.data.corrections``: the ``dcdp-record-corrections`` command."""

from lerobot_dcdp.data.corrections.cli import main

main()
