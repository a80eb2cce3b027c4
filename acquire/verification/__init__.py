"""The verification run (pure): its ISO 9283-style plan and the analysis of a finished session."""
