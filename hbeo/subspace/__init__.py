"""subspace"""
