"""`make bench`: performance figures as a printed table and JSON, never as test assertions."""
