"""One module per section of the report: each returns the data its template places."""
