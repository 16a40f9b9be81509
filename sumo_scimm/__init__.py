"""The ``sumo-scimm`` command line: the last stage of the data flow, the one package that
imports every other (docs/design.md §1). Each subcommand parses its options, calls one stage
function and prints the result."""
