"""Processing chains: one module per pipeline chain, each exposing `run(session, params, ctx)`."""
