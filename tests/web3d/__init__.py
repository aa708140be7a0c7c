"""Tests of the Web3D viewer (web/, web3d/, bench web)."""
