"""The one exception every stage raises for bad user input.

``sumo-scimm`` prints it as one line ``sumo-scimm: error: ...`` and exits with code 2
(sumo_scimm.cli). It lives alone here, with no imports, so that any stage can raise it
without loading the CLI (and with it libsumo)."""


class BadInput(Exception):
    """User error (a missing or malformed file, a bad option, an unwritable folder): its
    message names the problem and the fix in one line."""
