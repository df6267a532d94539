"""Helpers shared by integration tests: free ports, process management, real brokers."""
