"""The accuracy report (issue 17): what accuracy costs in time, on the theses' simulation cases."""
