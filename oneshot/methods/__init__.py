"""The methods of paper Section IV's comparison."""
