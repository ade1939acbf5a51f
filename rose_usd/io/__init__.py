"""Readers and writers of the file formats rose_usd exchanges (formats.md), apart from the math."""
