"""Independent generator of recordings for explain (issue 15, item 7); numpy only."""
