"""Offline runs on recorded bags: `online-em-slam run/compare/evaluate`, metrics, reports, plots."""
