"""scimm stage (SPEC §1); built by later issues."""
