// FractureCheck - conformance driver of the C# reader (used by the fracture tests).
//
//   mono FractureCheck.exe HEADER BINARY [--names] [--skip-crc] < impacts
//
// Same line protocol as engines/c/tools/fracture_check.c: impacts are 7 hex IEEE-754 doubles
// (point, impulse, threshold or "-"); answers "ok <site> <num_groups> g ... b ... a ... d ..."
// or "error <status>"; a file that does not load prints "load-error <message>" and exits with 2.
//
// MIT licence, Copyright (c) fracture developers.

using System;
using System.IO;
using System.Text;
using Fracture;

static class FractureCheck
{
    static double FromBits(string hex)
    {
        return BitConverter.Int64BitsToDouble(unchecked((long)Convert.ToUInt64(hex, 16)));
    }

    static string Bits(double value)
    {
        return BitConverter.DoubleToInt64Bits(value).ToString("x16");
    }

    static int Main(string[] args)
    {
        bool names = Array.IndexOf(args, "--names") >= 0, skipCrc = Array.IndexOf(args, "--skip-crc") >= 0;
        string[] paths = Array.FindAll(args, a => !a.StartsWith("--"));
        if (paths.Length != 2)
        {
            Console.Error.WriteLine("usage: FractureCheck HEADER BINARY [--names] [--skip-crc] < impacts");
            return 64;
        }
        FractureRuntime runtime;
        string error;
        if (!FractureRuntime.TryLoad(File.ReadAllBytes(paths[0]), File.ReadAllBytes(paths[1]), out runtime, out error,
                                     !skipCrc))
        {
            Console.WriteLine("load-error " + error);
            return 2;
        }
        var output = new StringBuilder();
        if (names)
        {
            output.Append("names");
            foreach (string name in runtime.FragmentNames)
            {
                byte[] utf8 = Encoding.UTF8.GetBytes(name);
                output.Append(' ').Append(utf8.Length == 0 ? "-" : BitConverter.ToString(utf8).Replace("-", "").ToLowerInvariant());
            }
            output.Append('\n');
        }
        var impact = new FractureImpact(runtime);
        string line;
        while ((line = Console.In.ReadLine()) != null)
        {
            string[] t = line.Split(new[] { ' ', '\t' }, StringSplitOptions.RemoveEmptyEntries);
            if (t.Length == 0)
                continue;
            double threshold = t[6] == "-" ? runtime.DefaultThreshold : FromBits(t[6]);
            FractureStatus status = runtime.Project(FromBits(t[0]), FromBits(t[1]), FromBits(t[2]), FromBits(t[3]),
                                                    FromBits(t[4]), FromBits(t[5]), threshold, impact);
            if (status != FractureStatus.Ok)
            {
                output.Append("error ").Append(status).Append('\n');
                continue;
            }
            output.Append("ok ").Append(impact.Site).Append(' ').Append(impact.NumGroups).Append(" g");
            foreach (int g in impact.Groups)
                output.Append(' ').Append(g);
            output.Append(" b");
            for (int m = 0; m < impact.Broken.Length; m++)
                if (impact.Broken[m])
                    output.Append(' ').Append(m);
            output.Append(" a");
            foreach (double a in impact.Alpha)
                output.Append(' ').Append(Bits(a));
            output.Append(" d");
            foreach (double x in impact.Displacement)
                output.Append(' ').Append(Bits(x));
            output.Append('\n');
        }
        Console.Out.Write(output.ToString());
        return 0;
    }
}
