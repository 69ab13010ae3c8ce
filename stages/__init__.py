"""Click commands, one module per command; thin wrappers around ``pipeline``."""
