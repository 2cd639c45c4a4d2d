"""The plants of the two papers: nonlinear equations and their linearisations."""
