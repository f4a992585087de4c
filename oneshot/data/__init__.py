"""Demonstrations (paper Section IV): what the expert records, collected and stored.

    npz         archives of named arrays, written so the same arrays are the same bytes, read without trust
    datasets    the dataset format (N tasks x K demos), its checks, save and load
    collection  collecting demonstrations with the expert, on every core
"""
