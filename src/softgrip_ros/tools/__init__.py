"""Installed user tools: softgrip_identify (and their log format)."""
