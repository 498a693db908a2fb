"""The Parquet manifest: schema and the root's rules, the frame file layout, part files, writer, reader and summaries, query, stats, synthetic rows."""
