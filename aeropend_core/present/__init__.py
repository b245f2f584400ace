"""Presentation of results: text, JSON and the HTML report with plots."""
